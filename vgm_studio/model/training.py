"""Training: labelled edges → a validated checkpoint.

Ambiguous and unlabelled edges are left out. Train and validation are split per (log, label)
so both sets see every log and both classes; training draws classes equally often, turns each
pair by a random rigid rotation, and stops when the validation loss stops improving.
"""

from __future__ import annotations

import copy
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn
from tqdm import tqdm

from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.core.hashing import content_hash
from vgm_studio.errors import InputError
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge, read_edges
from vgm_studio.model.checkpoint import Checkpoint, save_checkpoint
from vgm_studio.model.features import PairSample, figures_matrix, load_samples
from vgm_studio.model.metrics import binary_metrics
from vgm_studio.model.operating import precision_curve
from vgm_studio.model.registry import build_network, entry
from vgm_studio.model.score import ScoreModel
from vgm_studio.model.validator import (
    InputSpec,
    batched_logits,
    forward,
    input_spec,
    pick_device,
)
from vgm_studio.vgm.grid import VGMParams


@dataclass(frozen=True)
class TrainConfig:
    """How to train.

    Attributes:
        model: ``vgmnet``, ``vgmnet-paper``, ``rgb-baseline`` or ``score``.
        epochs: Epochs at most.
        batch_size: Pairs per step.
        lr: Adam learning rate.
        weight_decay: Adam weight decay.
        patience: Stop after this many epochs without a better validation loss.
        val_fraction: Share of each (log, label) group held out for validation.
        epoch_size: Class-balanced draws per epoch (None: the training set's size).
        max_train: Train on at most this many edges, drawn per (log, label) (slow models on
            a CPU); None uses all.
        augment: Turn each training pair by a random rigid rotation.
        seed: Seeds the split, the draws, the augmentation and the weights.
        device: ``auto``, ``cpu`` or ``cuda``.
        threads: torch CPU threads (None: torch's default).
        vgm: VGM parameters.
        hyper: Network hyper-parameters overriding the model's defaults.
    """

    model: str = "vgmnet"
    epochs: int = 12
    batch_size: int = 64
    lr: float = 2e-3
    weight_decay: float = 1e-4
    patience: int = 4
    val_fraction: float = 0.15
    epoch_size: int | None = 6000
    max_train: int | None = None
    augment: bool = True
    seed: int = 0
    device: str = "auto"
    threads: int | None = None
    vgm: VGMParams = field(default_factory=VGMParams)
    hyper: dict[str, Any] = field(default_factory=dict)


@dataclass
class LabelledSet:
    """Labelled edges with their samples, and where they came from."""

    edges: list[Edge]
    samples: list[PairSample]
    labels: NDArray[np.bool_]
    files: list[dict[str, Any]]

    @property
    def groups(self) -> list[str]:
        return [e.log_sha256 or e.log_path for e in self.edges]


def read_labelled(
    paths: Sequence[Path], scans: EdgeScans | None = None, progress: bool = True
) -> LabelledSet:
    """Reads edge files, keeps ``success`` and ``failure`` edges, loads their scans."""
    edges: list[Edge] = []
    files = []
    for path in paths:
        found = read_edges(path)
        kept = [e for e in found if e.label in ("success", "failure")]
        counts = Counter(e.label or "unlabelled" for e in found)
        files.append(
            {
                "path": str(path),
                "sha256": content_hash(Path(path)),
                "edges": len(found),
                "used": len(kept),
                "labels": dict(counts),
            }
        )
        edges.extend(kept)
    if not edges:
        raise InputError(
            paths[0] if paths else None, "no edge labelled success or failure in the given files"
        )
    samples = load_samples(
        edges, scans or EdgeScans(tuple(Path(p).parent for p in paths)), progress=progress
    )
    labels = np.array([e.label == "success" for e in edges], dtype=bool)
    return LabelledSet(edges, samples, labels, files)


def stratified_split(
    labels: NDArray[np.bool_], groups: Sequence[str], fraction: float, seed: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Indices (train, validation), holding out ``fraction`` of every (group, label)."""
    rng = np.random.default_rng(seed)
    train: list[int] = []
    val: list[int] = []
    keys: dict[tuple[str, bool], list[int]] = {}
    for i, (g, y) in enumerate(zip(groups, labels, strict=True)):
        keys.setdefault((g, bool(y)), []).append(i)
    for key in sorted(keys):
        idx = np.array(keys[key])
        rng.shuffle(idx)
        n_val = round(fraction * len(idx)) if len(idx) > 1 else 0
        val.extend(idx[:n_val])
        train.extend(idx[n_val:])
    return np.sort(np.array(train, dtype=np.int64)), np.sort(np.array(val, dtype=np.int64))


def _subset(
    idx: NDArray[np.int64], labels: NDArray[np.bool_], groups: Sequence[str], limit: int, seed: int
) -> NDArray[np.int64]:
    """At most ``limit`` of ``idx``, taking the same share of every (group, label)."""
    if len(idx) <= limit:
        return idx
    share = limit / len(idx)
    keep, _ = stratified_split(labels[idx], [groups[i] for i in idx], 1.0 - share, seed)
    return idx[keep]


def choose_threshold(labels: NDArray[np.bool_], probs: NDArray[np.float64]) -> float:
    """The p(success) cut with the best validation accuracy.

    Training draws both classes equally often, so its p = 0.5 is the cut for a 50/50 world;
    the validation split keeps the logs' own class mix, so the cut is chosen there. Ties go
    to the cut nearest 0.5.
    """
    cuts = np.round(np.arange(0.02, 0.99, 0.01), 2)
    acc = np.array([np.mean((probs >= c) == labels) for c in cuts])
    best = np.flatnonzero(acc >= acc.max() - 1e-12)
    return float(cuts[best[np.argmin(np.abs(cuts[best] - 0.5))]])


def balanced_draws(
    labels: NDArray[np.bool_], count: int, rng: np.random.Generator
) -> NDArray[np.int64]:
    """``count`` row indices drawn with replacement, each class half of the time."""
    pos = max(int(labels.sum()), 1)
    neg = max(int((~labels).sum()), 1)
    weights = np.where(labels, 0.5 / pos, 0.5 / neg)
    return rng.choice(len(labels), size=count, replace=True, p=weights / weights.sum())


def balanced_bce(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """BCE in which both classes weigh the same, whatever their counts."""
    pos = target.sum().clamp(min=1)
    neg = (1 - target).sum().clamp(min=1)
    w = torch.where(target > 0.5, 0.5 / pos, 0.5 / neg)
    return (
        nn.functional.binary_cross_entropy_with_logits(logits, target, reduction="none") * w
    ).sum()


def train_step(
    net: nn.Module,
    spec: InputSpec,
    samples: Sequence[PairSample],
    labels: NDArray[np.bool_],
    rotations: NDArray[np.float64] | None,
    optimiser: torch.optim.Optimizer,
    schedule: torch.optim.lr_scheduler.LRScheduler,
    device: torch.device,
) -> float:
    """One optimiser step on a batch (each pair turned by ``rotations``); returns its loss."""
    x, extra = spec.tensors(samples, device, rotations)
    y = torch.from_numpy(labels.astype(np.float32)).to(device)
    loss = nn.functional.binary_cross_entropy_with_logits(forward(net, x, extra), y)
    optimiser.zero_grad(set_to_none=True)
    loss.backward()
    optimiser.step()
    schedule.step()
    return float(loss.detach())


def train(
    data: LabelledSet,
    config: TrainConfig,
    out: Path,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> Checkpoint:
    """Trains ``config.model`` on ``data`` and writes the checkpoint to ``out``.

    Returns:
        The checkpoint written.
    """
    model = entry(config.model)
    start = time.perf_counter()
    torch.manual_seed(config.seed)
    if config.threads:
        torch.set_num_threads(config.threads)
    train_idx, val_idx = stratified_split(
        data.labels, data.groups, config.val_fraction, config.seed
    )
    if config.max_train is not None:
        train_idx = _subset(train_idx, data.labels, data.groups, config.max_train, config.seed)
    if len(set(data.labels[train_idx])) < 2:
        raise InputError(None, "training needs both success and failure edges")
    counts = {
        name: {"success": int(data.labels[idx].sum()), "failure": int((~data.labels[idx]).sum())}
        for name, idx in (("train", train_idx), ("validation", val_idx))
    }
    log(
        f"training {config.model} on {counts['train']['success']} success + "
        f"{counts['train']['failure']} failure edges; validating on "
        f"{counts['validation']['success']} + {counts['validation']['failure']}"
    )
    val_samples = [data.samples[i] for i in val_idx]
    val_labels = data.labels[val_idx]
    checkpoint = Checkpoint(model=config.model, vgm=config.vgm)
    if model.holds == "score":
        spread = bool(config.hyper.get("spread", False))
        x = figures_matrix([data.samples[i] for i in train_idx], spread)
        score = ScoreModel.fit(x, data.labels[train_idx])
        probs = score.predict(figures_matrix(val_samples, spread))
        checkpoint.hyper = {"spread": spread} if spread else {}
        checkpoint.score = asdict(score)
    else:
        device = pick_device(config.device)
        net, hyper = build_network(config.model, config.hyper)
        net = net.to(device).to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        spec = input_spec(config.model, hyper, config.vgm)
        state, history = _fit(
            net, spec, data, train_idx, val_samples, val_labels, config, device, progress, log
        )
        net.load_state_dict(state)
        probs = 1.0 / (1.0 + np.exp(-batched_logits(net, spec, val_samples, device, 128)))
        checkpoint.hyper = hyper
        checkpoint.device = str(device)
        checkpoint.history = history
        checkpoint.state_dict = {k: v.detach().cpu() for k, v in state.items()}
    threshold = choose_threshold(val_labels, probs) if len(val_idx) else DEFAULT_THRESHOLD
    checkpoint.threshold = threshold
    checkpoint.metrics = binary_metrics(val_labels, probs, threshold) if len(val_idx) else {}
    # The whole validation curve, so a cut can later be chosen by precision (--loop-precision).
    checkpoint.curve = precision_curve(val_labels, probs) if len(val_idx) else None
    checkpoint.training = {
        "files": data.files,
        "counts": counts,
        "seconds": time.perf_counter() - start,
        "config": {k: v for k, v in asdict(config).items() if k != "vgm"},
    }
    save_checkpoint(out, checkpoint)
    return checkpoint


def _fit(
    net: nn.Module,
    spec: InputSpec,
    data: LabelledSet,
    train_idx: NDArray[np.int64],
    val_samples: list[PairSample],
    val_labels: NDArray[np.bool_],
    config: TrainConfig,
    device: torch.device,
    progress: bool,
    log: Callable[[str], None],
) -> tuple[dict[str, torch.Tensor], list[dict[str, float]]]:
    rng = np.random.default_rng(config.seed)
    optimiser = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    per_epoch = config.epoch_size or len(train_idx)
    steps = math.ceil(per_epoch / config.batch_size)
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, config.lr, total_steps=config.epochs * steps
    )
    train_labels = data.labels[train_idx]
    val_target = torch.from_numpy(val_labels.astype(np.float32))
    best_loss, best_state, stale = math.inf, copy.deepcopy(net.state_dict()), 0
    history = []
    for epoch in range(1, config.epochs + 1):
        t0 = time.perf_counter()
        net.train()
        draws = train_idx[balanced_draws(train_labels, per_epoch, rng)]
        bar = tqdm(
            range(steps),
            desc=f"epoch {epoch}/{config.epochs}",
            unit="batch",
            disable=None if progress else True,
            leave=False,
        )
        total = 0.0
        for step in bar:
            idx = draws[step * config.batch_size : (step + 1) * config.batch_size]
            rot = rng.uniform(0, 2 * np.pi, len(idx)) if config.augment else None
            batch = [data.samples[i] for i in idx]
            total += train_step(
                net, spec, batch, data.labels[idx], rot, optimiser, schedule, device
            )
            bar.set_postfix(loss=f"{total / (step + 1):.3f}")
        logits = torch.from_numpy(batched_logits(net, spec, val_samples, device, 128))
        val_loss = float(balanced_bce(logits, val_target))
        acc = float(((logits > 0).numpy() == val_labels).mean()) if len(val_labels) else math.nan
        history.append(
            {
                "epoch": epoch,
                "train_loss": total / steps,
                "val_loss": val_loss,
                "val_accuracy": acc,
                "seconds": time.perf_counter() - t0,
            }
        )
        log(
            f"epoch {epoch:2d}: train loss {total / steps:.3f}  val loss {val_loss:.3f}  "
            f"val accuracy {acc:.3f}  ({time.perf_counter() - t0:.0f} s)"
        )
        if val_loss < best_loss - 1e-4:
            best_loss, best_state, stale = val_loss, copy.deepcopy(net.state_dict()), 0
        else:
            stale += 1
            if stale >= config.patience:
                log(f"stopping: no better validation loss for {config.patience} epochs")
                break
    return best_state, history
