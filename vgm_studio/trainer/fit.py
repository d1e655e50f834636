"""One training run of the background trainer: ``model/training.py``'s recipe, resumable.

The recipe is the offline trainer's (class-balanced draws, random rigid rotations, Adam with a
one-cycle schedule, early stopping on the held-out balanced loss, the p(success) cut chosen on
the held-out edges), with what a background trainer needs besides: it starts from a previous
version's weights, reports each epoch, and can be told to stop between batches.
"""

from __future__ import annotations

import copy
import math
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.model.checkpoint import Checkpoint
from vgm_studio.model.features import PairSample
from vgm_studio.model.metrics import binary_metrics
from vgm_studio.model.registry import MODELS, build_network
from vgm_studio.model.training import (
    balanced_bce,
    balanced_draws,
    choose_threshold,
    train_step,
)
from vgm_studio.model.validator import batched_logits, input_spec
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
    hyper: dict[str, Any] = field(default_factory=lambda: {"figures": True, "spread": True})
    vgm: VGMParams = field(default_factory=VGMParams)


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


EpochHook = Callable[[int, int], None]


def fit(
    samples: Sequence[PairSample],
    labels: NDArray[np.bool_],
    train_idx: NDArray[np.int64],
    held_idx: NDArray[np.int64],
    config: FitConfig,
    init: Checkpoint | None = None,
    on_epoch: EpochHook | None = None,
) -> FitResult:
    """Trains ``vgmnet`` on ``train_idx`` and judges it on ``held_idx``.

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
    device = torch.device("cpu")  # beside the app: the GPU, if any, is not ours to take
    net, hyper = build_network(MODEL, config.hyper)
    warm = init is not None and init.model == MODEL and init.hyper == hyper
    if warm:
        assert init is not None and init.state_dict is not None
        net.load_state_dict(init.state_dict)
    net = net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    spec = input_spec(MODEL, hyper, config.vgm)
    rng = np.random.default_rng(config.seed)
    optimiser = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    steps = math.ceil(config.epoch_size / config.batch_size)
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, config.lr, total_steps=config.epochs * steps
    )
    held_samples = [samples[i] for i in held_idx]
    held_labels = labels[held_idx]
    held_target = torch.from_numpy(held_labels.astype(np.float32))
    best_loss, best_state, stale = math.inf, copy.deepcopy(net.state_dict()), 0
    history: list[dict[str, float]] = []
    if on_epoch:
        on_epoch(0, config.epochs)
    for epoch in range(1, config.epochs + 1):
        t0 = time.perf_counter()
        net.train()
        draws = train_idx[balanced_draws(labels[train_idx], config.epoch_size, rng)]
        total = 0.0
        for step in range(steps):
            idx = draws[step * config.batch_size : (step + 1) * config.batch_size]
            rot = rng.uniform(0, 2 * np.pi, len(idx)) if config.augment else None
            batch = [samples[i] for i in idx]
            total += train_step(net, spec, batch, labels[idx], rot, optimiser, schedule, device)
        record = {"epoch": epoch, "train_loss": total / steps, "seconds": 0.0}
        if len(held_idx):
            logits = torch.from_numpy(batched_logits(net, spec, held_samples, device, 128))
            val_loss = float(balanced_bce(logits, held_target))
            record["val_loss"] = val_loss
        else:  # nothing held out yet: the last epoch is the best we know
            val_loss = -float(epoch)
        record["seconds"] = time.perf_counter() - t0
        history.append(record)
        if val_loss < best_loss - 1e-4:
            best_loss, best_state, stale = val_loss, copy.deepcopy(net.state_dict()), 0
        else:
            stale += 1
        if on_epoch:
            on_epoch(epoch, config.epochs)
        if stale >= config.patience:
            break
    net.load_state_dict(best_state)
    if len(held_idx):
        p = 1.0 / (1.0 + np.exp(-batched_logits(net, spec, held_samples, device, 128)))
        threshold = choose_threshold(held_labels, p)
        metrics = binary_metrics(held_labels, p, threshold)
    else:
        p, threshold, metrics = np.zeros(0), DEFAULT_THRESHOLD, {}
    return FitResult(
        state_dict={k: v.detach().cpu() for k, v in best_state.items()},
        hyper=hyper,
        threshold=threshold,
        metrics=metrics,
        held_out_p=p,
        history=history,
        warm_start=warm,
    )


def payload(result: FitResult, config: FitConfig, training: dict[str, Any]) -> Checkpoint:
    """The version as a checkpoint, so ``Validator`` and ``eval`` take it."""
    return Checkpoint(
        model=MODEL,
        vgm=config.vgm,
        hyper=result.hyper,
        threshold=result.threshold,
        metrics=result.metrics,
        training={**training, "config": {k: v for k, v in asdict(config).items() if k != "vgm"}},
        state_dict=result.state_dict,
        history=result.history,
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
