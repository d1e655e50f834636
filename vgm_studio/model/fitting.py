"""The one training loop: class-balanced draws, rigid rotations, one-cycle Adam, early stopping.

``vgm-studio train`` (``training.train``) and the background trainer (``trainer.fit``) both
train networks here; what differs between them (batch, rate, epoch size, a warm start, where
it runs, who hears of each epoch) comes in as parameters.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.model.features import PairSample
from vgm_studio.model.metrics import binary_metrics
from vgm_studio.model.occlusion import cut_sectors
from vgm_studio.model.precise_bn import precise_batch_norm
from vgm_studio.model.resume import RunState, load_run, run_key, save_run
from vgm_studio.model.validator import InputSpec, batched_logits, network_logits
from vgm_studio.progress import track

EpochHook = Callable[[int, int], None]


@dataclass(frozen=True)
class Recipe:
    """How a network is trained.

    Attributes:
        epochs: Epochs at most.
        epoch_size: Class-balanced draws per epoch (None: the training rows' count).
        batch_size: Pairs per step.
        lr: Peak Adam learning rate of the one-cycle schedule.
        weight_decay: Adam weight decay.
        patience: Stop after this many epochs without a better validation loss.
        augment: Turn each training pair by a random rigid rotation.
        occlude: Share of training draws that lose one scan's points in a random sector
            (``model/occlusion.py``); 0 cuts none.
        seed: Seeds the draws, the rotations and the cuts.
        bn_batches: Before each validation, batch norm's statistics are recomputed over this
            many batches of training draws (``precise_bn``); 0 keeps the running averages.
    """

    epochs: int = 30
    epoch_size: int | None = 6000
    batch_size: int = 64
    lr: float = 2e-3
    weight_decay: float = 1e-4
    patience: int = 8
    augment: bool = True
    occlude: float = 0.0
    seed: int = 0
    bn_batches: int = 0

    @classmethod
    def of(cls, config: object) -> Recipe:
        """The recipe held by a config that names the same fields (``TrainConfig``, the
        trainer's ``FitConfig``), so each spells its defaults but not the copy; a field the
        config does not name keeps the recipe's default."""
        defaults = cls()
        return cls(
            **{f.name: getattr(config, f.name, getattr(defaults, f.name)) for f in fields(cls)}
        )


@dataclass
class Fitted:
    """The best epoch's weights, its validation p(success), cut and figures, and the epochs."""

    state_dict: dict[str, torch.Tensor]
    val_p: NDArray[np.float64]
    threshold: float
    metrics: dict[str, Any]
    history: list[dict[str, float]]


@dataclass(frozen=True)
class Rows:
    """The data a network is fitted on: every row's sample and label, split in two."""

    samples: Sequence[PairSample]
    labels: NDArray[np.bool_]
    train: NDArray[np.int64]
    val: NDArray[np.int64]


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


def judge(labels: NDArray[np.bool_], p: NDArray[np.float64]) -> tuple[float, dict[str, Any]]:
    """The cut chosen on validation rows and the figures there; the default cut without any."""
    if not len(labels):
        return DEFAULT_THRESHOLD, {}
    threshold = choose_threshold(labels, p)
    return threshold, binary_metrics(labels, p, threshold)


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
    logits = network_logits(net, spec, samples, device, rotations)
    y = torch.from_numpy(labels.astype(np.float32)).to(device)
    if logits.dim() == 2:  # one logit per head (``VGMNet``'s blind head): each has its loss
        y = y[:, None].expand_as(logits)
    loss = nn.functional.binary_cross_entropy_with_logits(logits, y)
    optimiser.zero_grad(set_to_none=True)
    loss.backward()  # type: ignore[no-untyped-call]
    optimiser.step()
    schedule.step()
    return float(loss.detach())


def _p_success(
    net: nn.Module, spec: InputSpec, samples: Sequence[PairSample], device: torch.device
) -> NDArray[np.float64]:
    return np.asarray(1.0 / (1.0 + np.exp(-batched_logits(net, spec, samples, device, 128))))


def fit_network(
    net: nn.Module,
    spec: InputSpec,
    rows: Rows,
    recipe: Recipe,
    *,
    on_epoch: EpochHook | None = None,
    log: Callable[[str], None] | None = None,
    progress: bool = False,
    resume: Path | None = None,
) -> Fitted:
    """Trains ``net`` on ``rows.train``, stops early on ``rows.val``, and judges it there.

    Args:
        net: The network, where it is to train, with its starting weights (fresh or warm).
        spec: How its input batches are made.
        rows: The samples, labels and split.
        recipe: How to train.
        on_epoch: Called with (epochs done, epochs planned) before training and after each
            epoch; it may raise to stop the run.
        log: Told one line per epoch.
        progress: Show a progress bar per epoch.
        resume: Where the run's state is written after each epoch; a state there from the
            same recipe and rows is continued from (``model/resume.py``).

    Returns:
        The best epoch's weights (the last one's when nothing is held out) and its figures.
    """
    device = next(net.parameters()).device
    run = _Run(net, spec, rows, recipe, device)
    state = run.start(resume)
    if log is not None and state.epoch:
        log(f"resuming after epoch {state.epoch} of {recipe.epochs} from {resume}")
    if on_epoch:
        on_epoch(state.epoch, recipe.epochs)
    while state.epoch < recipe.epochs and state.stale < recipe.patience:
        state.epoch += 1
        record = run.epoch(state.epoch, progress)
        state.history.append(record)
        if log is not None:
            log(_epoch_line(record))
        # Nothing held out: the last epoch is the best we know.
        val_loss = record.get("val_loss", -float(state.epoch))
        if val_loss < state.best_loss - 1e-4:
            state.best_loss, state.best, state.stale = val_loss, _copy(net), 0
        else:
            state.stale += 1
        if resume is not None:
            save_run(resume, run.snapshot(state))
        if on_epoch:
            on_epoch(state.epoch, recipe.epochs)
        if state.stale >= recipe.patience and log is not None:
            log(f"stopping: no better validation loss for {recipe.patience} epochs")
    net.load_state_dict(state.best)
    return _judged(net, spec, run.val_samples, run.val_labels, device, state.best, state.history)


def _copy(net: nn.Module) -> dict[str, torch.Tensor]:
    return copy.deepcopy(net.state_dict())


class _Run:
    """One training run's moving parts: the optimiser, its schedule and the draws' generator."""

    def __init__(
        self, net: nn.Module, spec: InputSpec, rows: Rows, recipe: Recipe, device: torch.device
    ) -> None:
        self.net, self.spec, self.rows, self.recipe, self.device = net, spec, rows, recipe, device
        self.rng = np.random.default_rng(recipe.seed)
        self.optimiser = torch.optim.Adam(
            net.parameters(), lr=recipe.lr, weight_decay=recipe.weight_decay
        )
        self.per_epoch = recipe.epoch_size or len(rows.train)
        self.steps = math.ceil(self.per_epoch / recipe.batch_size)
        self.schedule = torch.optim.lr_scheduler.OneCycleLR(
            self.optimiser, recipe.lr, total_steps=recipe.epochs * self.steps
        )
        self.val_samples = [rows.samples[i] for i in rows.val]
        self.val_labels = rows.labels[rows.val]
        shapes = [(name, tuple(v.shape)) for name, v in net.state_dict().items()]
        self.key = run_key(recipe, repr((spec, shapes)), rows.labels, rows.train, rows.val)

    def start(self, resume: Path | None) -> RunState:
        """The state to go on from: the one saved at ``resume`` for this run, else epoch 0."""
        saved = load_run(resume, self.key) if resume is not None else None
        if saved is None:
            return self.snapshot(None)
        self.net.load_state_dict(saved.net)
        self.optimiser.load_state_dict(saved.optimiser)
        self.schedule.load_state_dict(saved.schedule)
        self.rng.bit_generator.state = saved.draws
        torch.set_rng_state(saved.torch_rng)
        return saved

    def snapshot(self, state: RunState | None) -> RunState:
        """``state``'s bookkeeping with the run's moving parts as they are now."""
        return RunState(
            key=self.key,
            epoch=state.epoch if state else 0,
            best_loss=state.best_loss if state else math.inf,
            stale=state.stale if state else 0,
            history=state.history if state else [],
            best=state.best if state else _copy(self.net),
            net=_copy(self.net),
            optimiser=copy.deepcopy(self.optimiser.state_dict()),
            schedule=self.schedule.state_dict(),
            draws=dict(self.rng.bit_generator.state),
            torch_rng=torch.get_rng_state(),
        )

    def epoch(self, epoch: int, progress: bool) -> dict[str, float]:
        """Trains one epoch of class-balanced draws; returns its losses and seconds."""
        t0 = time.perf_counter()
        rows = self.rows
        self.net.train()
        bar = track(
            self._batches(self.per_epoch, self.rng),
            f"epoch {epoch}/{self.recipe.epochs}",
            "batch",
            total=self.steps,
            enabled=progress,
            leave=False,  # the epoch's own log line follows
        )
        total = 0.0
        for step, (idx, rot, batch) in enumerate(bar):
            total += train_step(
                self.net,
                self.spec,
                batch,
                rows.labels[idx],
                rot,
                self.optimiser,
                self.schedule,
                self.device,
            )
            bar.set_postfix(loss=f"{total / (step + 1):.3f}")
        record = {"epoch": epoch, "train_loss": total / self.steps}
        if self.recipe.bn_batches:
            self._precise_batch_norm(epoch)
        if len(self.val_labels):
            record |= _validation(
                self.net, self.spec, self.val_samples, self.val_labels, self.device
            )
        record["seconds"] = time.perf_counter() - t0
        return record

    def _batches(
        self, count: int, rng: np.random.Generator
    ) -> Iterator[tuple[NDArray[np.int64], NDArray[np.float64] | None, list[PairSample]]]:
        """``count`` class-balanced training draws a batch at a time, each with its pairs'
        rotations (None without augmentation) and its pairs, sector-cut where the recipe
        says; drawn from ``rng`` as the batches are taken."""
        rows, recipe = self.rows, self.recipe
        draws = rows.train[balanced_draws(rows.labels[rows.train], count, rng)]
        for start in range(0, count, recipe.batch_size):
            idx = draws[start : start + recipe.batch_size]
            rot = rng.uniform(0, 2 * np.pi, len(idx)) if recipe.augment else None
            batch = [rows.samples[i] for i in idx]
            # Drawn only when asked, so a recipe without cuts draws as it always has.
            if recipe.occlude:
                batch = cut_sectors(batch, recipe.occlude, rng)
            yield idx, rot, batch

    def _precise_batch_norm(self, epoch: int) -> None:
        """Batch norm's statistics recomputed over ``bn_batches`` batches of training
        draws, from a generator of their own (seed, epoch): the run's draws, and a resumed
        run, stay as they were."""
        rng = np.random.default_rng([self.recipe.seed, epoch, 7])
        drawn = list(self._batches(self.recipe.bn_batches * self.recipe.batch_size, rng))
        batches = [batch for _, _, batch in drawn]
        precise_batch_norm(self.net, self.spec, batches, [rot for _, rot, _ in drawn], self.device)


def _validation(
    net: nn.Module,
    spec: InputSpec,
    samples: Sequence[PairSample],
    labels: NDArray[np.bool_],
    device: torch.device,
) -> dict[str, float]:
    """The balanced loss and the accuracy at p = 0.5 on the validation rows."""
    logits = torch.from_numpy(batched_logits(net, spec, samples, device, 128))
    target = torch.from_numpy(labels.astype(np.float32))
    return {
        "val_loss": float(balanced_bce(logits, target)),
        "val_accuracy": float(((logits > 0).numpy() == labels).mean()),
    }


def _epoch_line(record: dict[str, float]) -> str:
    line = f"epoch {int(record['epoch']):2d}: train loss {record['train_loss']:.3f}"
    if "val_loss" in record:
        line += f"  val loss {record['val_loss']:.3f}  val accuracy {record['val_accuracy']:.3f}"
    return line + f"  ({record['seconds']:.0f} s)"


def _judged(
    net: nn.Module,
    spec: InputSpec,
    samples: Sequence[PairSample],
    labels: NDArray[np.bool_],
    device: torch.device,
    state: dict[str, torch.Tensor],
    history: list[dict[str, float]],
) -> Fitted:
    """The fitted weights with the cut and figures chosen on the validation rows."""
    p = _p_success(net, spec, samples, device) if len(labels) else np.zeros(0)
    threshold, metrics = judge(labels, p)
    weights = {k: v.detach().cpu() for k, v in state.items()}
    return Fitted(weights, p, threshold, metrics, history)
