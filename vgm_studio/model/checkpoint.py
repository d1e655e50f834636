"""Model checkpoints: weights plus everything needed to trust them later.

A checkpoint records the model name and hyper-parameters, the VGM parameters it was trained
on, the training files (paths, hashes, edge counts) and its validation metrics.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, get_args

import torch

from vgm_studio.errors import InputError
from vgm_studio.model.checkpoint_schema import ModelName, parse_checkpoint_meta
from vgm_studio.vgm.grid import VGMParams

FORMAT = "vgm-studio-model/1"
MODEL_NAMES: tuple[str, ...] = get_args(ModelName)


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    """Writes atomically: a crash never leaves half a checkpoint behind."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    try:
        torch.save({"format": FORMAT, **payload}, tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_checkpoint(path: Path, expect_vgm: VGMParams | None = None) -> dict[str, Any]:
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
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a damaged or foreign file
        raise InputError(path, f"not a readable model checkpoint ({type(exc).__name__})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise InputError(path, f"not a VGM Studio model (expected format {FORMAT})")
    vgm = VGMParams(**parse_checkpoint_meta(ckpt, path).vgm.model_dump())
    if expect_vgm is not None and vgm != expect_vgm:
        raise InputError(
            path,
            f"trained on VGMs of size {vgm.size}, resolution "
            f"{vgm.resolution} m, sigma {vgm.sigma} m, but size "
            f"{expect_vgm.size}, resolution {expect_vgm.resolution} m, sigma "
            f"{expect_vgm.sigma} m were asked for; retrain or use matching VGMs",
        )
    return ckpt
