"""One training run of the background trainer: the shared loop (``model/fitting.py``), resumable.

The loop is ``vgm-studio train``'s (class-balanced draws, random rigid rotations, Adam with a
one-cycle schedule, early stopping on the held-out balanced loss, the p(success) cut chosen on
the held-out edges); what the background trainer adds is its own recipe (small batches, an
epoch of 1024 draws), a warm start from a previous version's weights, the CPU, and a hook
told of each epoch that can stop the run.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from vgm_studio.model.checkpoint import Checkpoint
from vgm_studio.model.context import DEFAULT_CONTEXT, Context
from vgm_studio.model.features import PairSample
from vgm_studio.model.fitting import EpochHook, Recipe, Rows, fit_network
from vgm_studio.model.operating import PrecisionCurve, precision_curve
from vgm_studio.model.registry import MODELS, build_network, default_hyper
from vgm_studio.model.validator import input_spec
from vgm_studio.vgm.grid import VGMParams

# The model the background trainer trains: the registry's one that it can.
MODEL = next(m.name for m in MODELS if m.background)


@dataclass(frozen=True)
class FitConfig:
    """How each version is trained.

    Attributes:
        epochs: Epochs at most.
        epoch_size: Class-balanced draws per epoch (with replacement, whatever the set's size).
        batch_size: Pairs per step.
        lr: Peak Adam learning rate of the one-cycle schedule.
        weight_decay: Adam weight decay.
        patience: Stop after this many epochs without a better held-out loss.
        augment: Turn each training pair by a random rigid rotation.
        seed: Seeds the draws, the augmentation and fresh weights.
        hyper: ``vgmnet`` hyper-parameters (``SparseConfig`` fields).
        vgm: VGM parameters.
        context: How each side of a pair is drawn (``model/context.py``): the bundled model's,
            so that a version can start from it.
    """

    # Measured on simulated corridor loops, 25 to 300 labels (BENCHMARKS.md, background trainer):
    # small batches and a lower peak rate than ``vgm-studio train`` learn more from few labels.
    epochs: int = 12
    epoch_size: int = 1024
    batch_size: int = 16
    lr: float = 3e-3
    weight_decay: float = 1e-4
    patience: int = 4
    augment: bool = True
    seed: int = 0
    hyper: dict[str, Any] = field(default_factory=lambda: default_hyper(MODEL))
    vgm: VGMParams = field(default_factory=VGMParams)
    context: Context = DEFAULT_CONTEXT

    def recipe(self) -> Recipe:
        """The shared training loop's part of the config."""
        return Recipe.of(self)


@dataclass
class FitResult:
    """A trained version: weights, the cut, held-out figures and the epochs' history."""

    state_dict: dict[str, torch.Tensor]
    hyper: dict[str, Any]
    threshold: float
    metrics: dict[str, Any]
    held_out_p: NDArray[np.float64]
    history: list[dict[str, float]]
    warm_start: bool
    curve: PrecisionCurve | None = None


def fit(
    samples: Sequence[PairSample],
    labels: NDArray[np.bool_],
    train_idx: NDArray[np.int64],
    held_idx: NDArray[np.int64],
    config: FitConfig,
    init: Checkpoint | None = None,
    on_epoch: EpochHook | None = None,
) -> FitResult:
    """Trains the background model on ``train_idx`` and judges it on ``held_idx``.

    Args:
        samples: Every row's sample.
        labels: True for success, one per row.
        train_idx: Rows to train on (both classes needed).
        held_idx: Rows to stop early and choose the cut on (may be empty).
        config: The recipe.
        init: A previous checkpoint to start from; ignored when its network differs.
        on_epoch: Called with (epochs done, epochs planned) before training and after each
            epoch; it may raise to stop the run.

    Returns:
        The best epoch's weights and figures.
    """
    torch.manual_seed(config.seed)
    # Built on the CPU and trained there: beside the app, the GPU, if any, is not ours to take.
    net, hyper = build_network(MODEL, config.hyper)
    weights = init.starts(MODEL, hyper, config.vgm, config.context) if init is not None else None
    warm = weights is not None
    if weights is not None:
        net.load_state_dict(weights)
    net = net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    spec = input_spec(MODEL, hyper, config.vgm)
    rows = Rows(samples, labels, train_idx, held_idx)
    fitted = fit_network(net, spec, rows, config.recipe(), on_epoch=on_epoch)
    return FitResult(
        state_dict=fitted.state_dict,
        hyper=hyper,
        threshold=fitted.threshold,
        metrics=fitted.metrics,
        held_out_p=fitted.val_p,
        history=fitted.history,
        warm_start=warm,
        # Kept so that a version can serve ``--loop-precision`` like a trained checkpoint.
        curve=precision_curve(labels[held_idx], fitted.val_p) if len(held_idx) else None,
    )


def payload(result: FitResult, config: FitConfig, training: dict[str, Any]) -> Checkpoint:
    """The version as a checkpoint, so ``Validator`` and ``eval`` take it."""
    return Checkpoint(
        model=MODEL,
        vgm=config.vgm,
        context=config.context,
        hyper=result.hyper,
        threshold=result.threshold,
        metrics=result.metrics,
        training={**training, "config": {k: v for k, v in asdict(config).items() if k != "vgm"}},
        state_dict=result.state_dict,
        history=result.history,
        curve=result.curve,
    )


def write_checkpoint(folder: Path, checkpoint: Checkpoint) -> Path:
    """Writes a checkpoint to a fresh file in ``folder``, flushed to disk; returns its path.

    The file is whole before ``register_model`` renames it into place, so a registered
    version's file can never be half written, even after a power cut.
    """
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".pending-", suffix=".pt", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(checkpoint.to_dict(), f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return Path(tmp)
