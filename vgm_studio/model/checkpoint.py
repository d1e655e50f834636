"""Model checkpoints: weights plus everything needed to trust them later.

A checkpoint records the model name and hyper-parameters, the VGM parameters it was trained
on, the p(success) cut chosen on validation, the training files (paths, hashes, edge counts)
and its validation metrics. On disk it is a ``torch.save``d dict (``vgm-studio-model/1``);
files written before ``Checkpoint`` existed read the same.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

from vgm_studio.atomic import atomic_path
from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.errors import InputError
from vgm_studio.model.checkpoint_schema import parse_checkpoint_meta
from vgm_studio.model.context import Context
from vgm_studio.model.operating import PrecisionCurve, threshold_for_precision
from vgm_studio.model.registry import build_network
from vgm_studio.vgm.grid import VGMParams

FORMAT = "vgm-studio-model/1"


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


@dataclass
class Checkpoint:
    """A trained validator.

    Attributes:
        model: The registry's name of the model.
        vgm: The VGM parameters it was trained on.
        context: The neighbours each side of a pair was drawn with (``model/context.py``);
            a checkpoint without one read single scans.
        hyper: Its hyper-parameters (defaults included for networks).
        threshold: p(success) at or above which it says success.
        metrics: Validation figures (``binary_metrics``), {} without validation edges.
        training: How it was trained: files, counts, seconds, the config.
        state_dict: Network weights (networks).
        score: The fitted constants (the score model).
        history: One record per epoch.
        device: Where it was trained.
        created: When (UTC, ISO 8601).
        curve: Validation precision and recall at every cut, for choosing a cut by
            precision; None in checkpoints written before it was kept.
    """

    model: str
    vgm: VGMParams = field(default_factory=VGMParams)
    context: Context = field(default_factory=Context)
    hyper: dict[str, Any] = field(default_factory=dict)
    threshold: float = DEFAULT_THRESHOLD
    metrics: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    state_dict: dict[str, torch.Tensor] | None = None
    score: dict[str, Any] | None = None
    history: list[dict[str, Any]] = field(default_factory=list)
    device: str = "cpu"
    created: str = field(default_factory=_now)
    curve: PrecisionCurve | None = None

    def starts(
        self, model: str, hyper: dict[str, Any], vgm: VGMParams, context: Context
    ) -> dict[str, torch.Tensor] | None:
        """Its weights, when they fit a ``model`` network built with ``hyper`` that reads
        ``vgm`` VGMs drawn with ``context`` (a warm start); None when it is another model or
        other settings."""
        if self.model != model or self.vgm != vgm or self.context != context:
            return None
        # Completed with today's defaults: a field added since it was saved (``inliers``) is
        # absent from its hyper-parameters, and was then what its default is now.
        _net, mine = build_network(model, self.hyper)
        return self.state_dict if mine == hyper else None

    def to_dict(self) -> dict[str, Any]:
        """The on-disk layout."""
        out: dict[str, Any] = {
            "format": FORMAT,
            **self.__dict__,
            "vgm": asdict(self.vgm),
            "context": asdict(self.context),
        }
        out["curve"] = self.curve.to_dict() if self.curve is not None else None
        return {k: v for k, v in out.items() if v is not None}

    @classmethod
    def from_dict(cls, content: dict[str, Any]) -> Checkpoint:
        """Reads the on-disk layout (any version of it since ``vgm-studio-model/1``)."""
        threshold = content.get("threshold")
        return cls(
            model=content["model"],
            vgm=VGMParams(**content["vgm"]),
            context=Context(**(content.get("context") or {})),
            hyper=dict(content.get("hyper") or {}),
            threshold=DEFAULT_THRESHOLD if threshold is None else float(threshold),
            metrics=dict(content.get("metrics") or {}),
            curve=PrecisionCurve.from_dict(content["curve"]) if content.get("curve") else None,
            training=dict(content.get("training") or {}),
            state_dict=content.get("state_dict"),
            score=content.get("score"),
            history=list(content.get("history") or []),
            device=str(content.get("device", "cpu")),
            created=str(content.get("created", "")),
        )


def save_checkpoint(path: Path, checkpoint: Checkpoint) -> None:
    """Writes atomically: a crash never leaves half a checkpoint behind."""
    with atomic_path(path) as tmp:
        torch.save(checkpoint.to_dict(), tmp)


def load_checkpoint(path: Path, expect_vgm: VGMParams | None = None) -> Checkpoint:
    """Reads and checks a checkpoint.

    Args:
        path: The ``.pt`` file.
        expect_vgm: Refuse a checkpoint trained on other VGM parameters.

    Raises:
        InputError: Missing, unreadable, not ours, unknown model, or other VGM parameters.
    """
    if not path.is_file():
        raise InputError(path, "no such model file")
    try:
        content = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a damaged or foreign file
        raise InputError(path, f"not a readable model checkpoint ({type(exc).__name__})") from None
    if not isinstance(content, dict) or content.get("format") != FORMAT:
        raise InputError(path, f"not a VGM Studio model (expected format {FORMAT})")
    parse_checkpoint_meta(content, path)  # types and ranges, before anything reads them
    checkpoint = Checkpoint.from_dict(content)
    vgm = checkpoint.vgm
    if expect_vgm is not None and vgm != expect_vgm:
        raise InputError(
            path,
            f"trained on VGMs of size {vgm.size}, resolution "
            f"{vgm.resolution} m, sigma {vgm.sigma} m, but size "
            f"{expect_vgm.size}, resolution {expect_vgm.resolution} m, sigma "
            f"{expect_vgm.sigma} m were asked for; retrain or use matching VGMs",
        )
    return checkpoint


def precision_threshold(checkpoint: Checkpoint, precision: float, path: Path | None) -> float:
    """The lowest p(success) cut whose validation precision reaches ``precision``.

    Raises:
        InputError: The checkpoint keeps no validation curve (written before curves were
            kept), or no cut on it reaches ``precision``.
    """
    curve = checkpoint.curve
    if curve is None:
        raise InputError(
            path,
            "keeps no validation precision curve, so --loop-precision cannot choose a "
            "threshold; retrain it or use --loop-threshold",
        )
    cut = threshold_for_precision(curve, precision)
    if cut is None:
        raise InputError(
            path,
            f"no threshold reaches validation precision {precision:g} "
            f"(best {max(curve.precision):.4f}); ask for less or use --loop-threshold",
        )
    return cut
