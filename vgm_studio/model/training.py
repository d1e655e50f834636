"""Training: labelled edges → a validated checkpoint.

Ambiguous and unlabelled edges are left out. Train and validation are split per (log, label)
so both sets see every log and both classes; networks are trained by ``fitting.fit_network``
(the loop the background trainer shares), the score model in closed form.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from vgm_studio.core.hashing import content_hash
from vgm_studio.errors import InputError
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge, read_edges
from vgm_studio.model.calibration import calibrate, calibration_mask
from vgm_studio.model.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from vgm_studio.model.context import Context
from vgm_studio.model.features import PairSample, figures_matrix, load_samples
from vgm_studio.model.fitting import Recipe, Rows, choose_threshold, fit_network
from vgm_studio.model.registry import build_network, entry
from vgm_studio.model.score import ScoreModel
from vgm_studio.model.validator import input_spec, pick_device
from vgm_studio.vgm.grid import VGMParams

# Labelled edges of each class a run needs. A share of each class is held out (--val-fraction,
# 0.15): early stopping, the p(success) cut and the reported figures are all read there, and
# with fewer than 10 a class has at most one validation edge (round(0.15 × 9) = 1), so one
# edge would decide the cut and the figures; with none (3 labels) there is nothing to read
# them from at all, and the run trains every epoch for figures that cannot exist.
MIN_PER_CLASS = 10

__all__ = [
    "MIN_PER_CLASS",
    "LabelledSet",
    "TrainConfig",
    "choose_threshold",
    "read_labelled",
    "stratified_split",
    "train",
]


@dataclass(frozen=True)
class TrainConfig:
    """How to train.

    Attributes:
        model: A name in the model registry (``model/registry.py``).
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
        occlude: Share of training draws that lose one scan's points in a random sector.
        seed: Seeds the split, the draws, the augmentation and the weights.
        bn_batches: Batches of training draws batch norm's statistics are recomputed over
            before each validation (``model/precise_bn.py``); 0 keeps the running averages.
        device: ``auto``, ``cpu`` or ``cuda``.
        threads: torch CPU threads (None: torch's default).
        init: A checkpoint of the same model and hyper-parameters whose weights the run
            starts from (a second schedule on a slow network); None starts fresh.
        vgm: VGM parameters.
        context: The neighbours each side of a pair is drawn with (``model/context.py``);
            the edges must be read with the same (``read_labelled``).
        hyper: Network hyper-parameters overriding the model's defaults.
    """

    # The training loop's fields default to the loop's own recipe (``fitting.Recipe``).
    model: str = "vgmnet"
    epochs: int = Recipe.epochs
    batch_size: int = Recipe.batch_size
    lr: float = Recipe.lr
    weight_decay: float = Recipe.weight_decay
    patience: int = Recipe.patience
    val_fraction: float = 0.15
    epoch_size: int | None = Recipe.epoch_size
    max_train: int | None = None
    augment: bool = Recipe.augment
    occlude: float = Recipe.occlude
    seed: int = Recipe.seed
    bn_batches: int = Recipe.bn_batches
    device: str = "auto"
    threads: int | None = None
    init: str | None = None
    vgm: VGMParams = field(default_factory=VGMParams)
    context: Context = field(default_factory=Context)
    hyper: dict[str, Any] = field(default_factory=dict)

    def recipe(self) -> Recipe:
        """The training loop's part of the config."""
        return Recipe.of(self)


@dataclass
class LabelledSet:
    """Labelled edges with their samples, and where they came from."""

    edges: list[Edge]
    samples: list[PairSample]
    labels: NDArray[np.bool_]
    files: list[dict[str, Any]]
    context: Context = field(default_factory=Context)  # what each side was drawn with

    @property
    def groups(self) -> list[str]:
        return [e.log_sha256 or e.log_path for e in self.edges]


def read_labelled(
    paths: Sequence[Path],
    scans: EdgeScans | None = None,
    progress: bool = True,
    context: Context | None = None,
    to_train: bool = False,
) -> LabelledSet:
    """Reads edge files, keeps ``success`` and ``failure`` edges, loads their scans (each
    side its scan's local map with a ``context``, ``model/context.py``).

    With ``to_train``, too few edges of a class (``check_enough``) are refused before any
    scan is loaded.
    """
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
    labels = np.array([e.label == "success" for e in edges], dtype=bool)
    if to_train:
        check_enough(labels, [str(p) for p in paths])
    samples = load_samples(
        edges,
        scans or EdgeScans(tuple(Path(p).parent for p in paths)),
        progress=progress,
        context=context,
    )
    return LabelledSet(edges, samples, labels, files, context or Context())


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


def _split(
    data: LabelledSet, config: TrainConfig
) -> tuple[NDArray[np.int64], NDArray[np.int64], dict[str, dict[str, int]]]:
    """Rows to train and validate on, and how many of each class each holds.

    Raises:
        InputError: Fewer than ``MIN_PER_CLASS`` edges of a class, or a training split
            without both classes.
    """
    check_enough(data.labels, [str(f["path"]) for f in data.files])
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
    return train_idx, val_idx, counts


def check_enough(labels: NDArray[np.bool_], paths: Sequence[str]) -> None:
    """Refuses labelled edges too few to train on and judge (``MIN_PER_CLASS`` a class).

    Args:
        labels: True for each ``success`` edge, False for each ``failure``.
        paths: The files they came from, named in the refusal.

    Raises:
        InputError: Naming the file (or how many) and the counts.
    """
    success = int(labels.sum())
    failure = len(labels) - success
    if min(success, failure) >= MIN_PER_CLASS:
        return
    where = paths[0] if len(paths) == 1 else None
    held = "" if where else (f"{len(paths)} files: " if paths else "the edges: ")
    raise InputError(
        where,
        f"{held}{success} success and {failure} failure edges; training needs at least "
        f"{MIN_PER_CLASS} of each (a share of each class is held out to stop early, choose "
        "the p(success) cut and give the figures): label more edges",
    )


def train(
    data: LabelledSet,
    config: TrainConfig,
    out: Path,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> Checkpoint:
    """Trains ``config.model`` on ``data`` and writes the checkpoint to ``out``.

    A network's run state is kept in ``out`` + ``.partial`` after each epoch and removed
    when the checkpoint is written: stopped, the same call goes on after the last epoch.

    Returns:
        The checkpoint written.
    """
    if data.context != config.context:
        raise ValueError(
            f"the edges were read with {data.context}, but the config asks for {config.context}"
        )
    model = entry(config.model)
    start = time.perf_counter()
    torch.manual_seed(config.seed)
    if config.threads:
        torch.set_num_threads(config.threads)
    train_idx, val_idx, counts = _split(data, config)
    log(
        f"training {config.model} on {counts['train']['success']} success + "
        f"{counts['train']['failure']} failure edges; validating on "
        f"{counts['validation']['success']} + {counts['validation']['failure']}"
    )
    rows = Rows(data.samples, data.labels, train_idx, val_idx)
    # A stopped network run goes on from here when the same command is given again.
    resume = out.with_name(out.name + ".partial")
    if model.holds == "score":
        checkpoint, val_p = _fit_score(rows, config)
    else:
        checkpoint, val_p = _fit_network(rows, config, progress, log, resume)
    real = calibration_mask([data.edges[i] for i in val_idx], data.labels[val_idx])
    calibrate(checkpoint, data.labels[val_idx], val_p, real)
    checkpoint.training = {
        "files": data.files,
        "counts": counts,
        "seconds": time.perf_counter() - start,
        "config": {k: v for k, v in asdict(config).items() if k not in ("vgm", "context")},
        "calibration_edges": int(real.sum()),
    }
    save_checkpoint(out, checkpoint)
    resume.unlink(missing_ok=True)
    return checkpoint


def _fit_score(rows: Rows, config: TrainConfig) -> tuple[Checkpoint, NDArray[np.float64]]:
    """The score model, fitted in closed form; and its p(success) on the validation rows."""
    spread = bool(config.hyper.get("spread", False))
    score = ScoreModel.fit(
        figures_matrix([rows.samples[i] for i in rows.train], spread), rows.labels[rows.train]
    )
    probs = score.predict(figures_matrix([rows.samples[i] for i in rows.val], spread))
    checkpoint = Checkpoint(
        model=config.model,
        vgm=config.vgm,
        context=config.context,
        hyper={"spread": spread} if spread else {},
        score=asdict(score),
    )
    return checkpoint, probs


def _fit_network(
    rows: Rows, config: TrainConfig, progress: bool, log: Callable[[str], None], resume: Path
) -> tuple[Checkpoint, NDArray[np.float64]]:
    """A network, trained by the shared loop from fresh weights (or from ``resume``); and its
    p(success) on the validation rows."""
    device = pick_device(config.device)
    net, hyper = build_network(config.model, config.hyper)
    if config.init is not None:
        weights = _initial_weights(Path(config.init), config.model, hyper, config)
        net.load_state_dict(weights)
    net = net.to(device).to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    spec = input_spec(config.model, hyper, config.vgm)
    fitted = fit_network(
        net, spec, rows, config.recipe(), log=log, progress=progress, resume=resume
    )
    checkpoint = Checkpoint(
        model=config.model,
        vgm=config.vgm,
        context=config.context,
        hyper=hyper,
        state_dict=fitted.state_dict,
        history=fitted.history,
        device=str(device),
    )
    return checkpoint, fitted.val_p


def _initial_weights(
    path: Path, model: str, hyper: dict[str, Any], config: TrainConfig
) -> dict[str, torch.Tensor]:
    """The weights of the checkpoint at ``path``, refused unless it is ``model`` with
    ``hyper`` on the config's VGMs and context."""
    start = load_checkpoint(path)
    weights = start.starts(model, hyper, config.vgm, config.context)
    if weights is None:
        raise InputError(
            path, f"is a {start.model} checkpoint with other settings; --init needs a {model} one"
        )
    return weights
