"""The schema of a model checkpoint's metadata, declared once.

A checkpoint is read with ``weights_only`` (no code runs), but its metadata still comes from a
file: the model name, VGM parameters and threshold are checked here before anything uses them.
The weights themselves are checked by ``load_state_dict``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from vgm_studio.errors import InputError
from vgm_studio.matching.edge_schema import Finite, describe
from vgm_studio.model.registry import MODEL_NAMES


def _known_model(name: str) -> str:
    if name not in MODEL_NAMES:
        raise ValueError(f"unknown model (expected one of {', '.join(MODEL_NAMES)})")
    return name


class VGMMeta(BaseModel):
    """``VGMParams`` as stored: cells per side, cell edge and regulariser in metres."""

    model_config = ConfigDict(extra="forbid")

    size: Annotated[int, Field(ge=8, le=4096)]
    resolution: Annotated[Finite, Field(gt=0.0, le=10.0)]
    sigma: Annotated[Finite, Field(gt=0.0, le=10.0)]


class ContextMeta(BaseModel):
    """``Context`` as stored: the neighbours each side of a pair was drawn with."""

    model_config = ConfigDict(extra="forbid")

    neighbours: Annotated[int, Field(ge=0, le=64)]
    spacing: Annotated[Finite, Field(ge=0.0, le=100.0)]
    turn: Annotated[Finite, Field(ge=0.0, le=7.0)]
    reach: Annotated[Finite, Field(ge=0.0, le=1000.0)]
    scans: Annotated[int, Field(ge=1, le=1_000_000)]
    matched: bool = True
    min_inliers: Annotated[Finite, Field(ge=0.0, le=1.0)] = 0.3
    covisible: bool = False
    view_margin: Annotated[Finite, Field(ge=0.0, le=100.0)] = 0.3


class CheckpointMeta(BaseModel):
    """What every checkpoint carries besides its weights; other keys are kept as they are."""

    model_config = ConfigDict(extra="allow")

    format: str
    model: Annotated[str, Field(max_length=64), AfterValidator(_known_model)]
    vgm: VGMMeta
    context: ContextMeta | None = None
    threshold: Annotated[Finite, Field(ge=0.0, le=1.0)] | None = None
    hyper: dict[str, Any] | None = None
    metrics: dict[str, Any] | None = None


def parse_checkpoint_meta(ckpt: dict[str, Any], path: Path) -> CheckpointMeta:
    """Validates a loaded checkpoint's metadata.

    Raises:
        InputError: ``file: field: what is wrong``.
    """
    meta = {k: v for k, v in ckpt.items() if k not in ("state_dict", "score")}
    try:
        return CheckpointMeta.model_validate(meta)
    except ValidationError as exc:
        raise InputError(path, f"not a usable model checkpoint: {describe(exc)}") from None
