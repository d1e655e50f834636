"""What the trainer learns from: the workspace's human labels, a held-out split that stays put,
and labelled ``--base`` files.

The held-out split is sticky: an edge held out once stays held out (it is kept in the store),
so no version ever trains on an edge another version is judged on, and two versions are
compared on the same edges. New labelled edges are dealt to it per (log, label) so that each
such group keeps its share held out, as ``training.stratified_split`` does for a file.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.labels.store import LabelStore
from vgm_studio.labels.votes import human_label
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.model.context import Context
from vgm_studio.model.features import PairSample, load_samples
from vgm_studio.model.training import read_labelled, stratified_split


def majority_labels(store: LabelStore) -> dict[str, bool]:
    """edge_id → True for success, by majority of the edge's annotators; ties left out."""
    out = {}
    for edge_id, votes in store.label_map().items():
        label = human_label(votes)
        if label is not None:
            out[edge_id] = label == "success"
    return out


def _rank(seed: int, edge_id: str) -> str:
    """A fixed pseudo-random order of edges, the same in every run."""
    return hashlib.sha256(f"{seed}:{edge_id}".encode()).hexdigest()


def held_out_split(
    store: LabelStore,
    labels: dict[str, bool],
    groups: dict[str, str],
    fraction: float,
    seed: int = 0,
) -> set[str]:
    """The held-out edges among ``labels``, dealing new ones to keep each (group, label) share.

    Args:
        store: Where the split is kept (table ``trainer_split``).
        labels: edge_id → success, for every labelled edge.
        groups: edge_id → its log (hash).
        fraction: Share of each (group, label) to hold out.
        seed: Decides which new edges are held out.

    Returns:
        The held-out edge ids (a subset of ``labels``).
    """

    def deal(known: dict[str, int]) -> list[tuple[str, int]]:
        strata: dict[tuple[str, bool], list[str]] = {}
        for edge_id, y in labels.items():
            strata.setdefault((groups.get(edge_id, ""), y), []).append(edge_id)
        new: list[tuple[str, int]] = []
        for members in strata.values():
            held = sum(1 for e in members if known.get(e) == 1)
            # A lone edge of its kind trains: holding it out would leave training without it.
            target = round(fraction * len(members)) if len(members) > 1 else 0
            for edge_id in sorted(
                (e for e in members if e not in known), key=lambda e: _rank(seed, e)
            ):
                flag = int(held < target)
                held += flag
                new.append((edge_id, flag))
        return new

    known = store.trainer.deal_split(deal)
    return {e for e in labels if known[e] == 1}


@dataclass
class TrainingSet:
    """Samples with labels, split into training and held-out rows.

    Attributes:
        edge_ids: One per row.
        samples: One per row.
        labels: True for success.
        train: Row indices to train on (workspace and base edges).
        held_out: Row indices to judge on (workspace edges only).
        workspace_labels: How many workspace edges with a human label are in it.
    """

    edge_ids: list[str]
    samples: list[PairSample]
    labels: NDArray[np.bool_]
    train: NDArray[np.int64]
    held_out: NDArray[np.int64]
    workspace_labels: int

    def counts(self) -> dict[str, dict[str, int]]:
        return {
            name: {
                "success": int(self.labels[idx].sum()),
                "failure": int((~self.labels[idx]).sum()),
            }
            for name, idx in (("train", self.train), ("held_out", self.held_out))
        }


@dataclass
class SampleCache:
    """Every workspace edge's sample, read from its log once per trainer process.

    The trainer predicts every edge after each promotion and trains on any of them, so all
    are read at start (a few kB each); edges added to the workspace later are read then.
    """

    store: LabelStore
    context: Context  # how each side is drawn: the trainer's (``FitConfig.context``)
    scans: EdgeScans = field(default_factory=EdgeScans)
    samples: dict[str, PairSample] = field(default_factory=dict)
    edges: dict[str, Edge] = field(default_factory=dict)

    def refresh(self) -> None:
        """Reads the samples of edges added since the last call."""
        if len(self.edges) == self.store.count_edges():
            return
        fresh = [e for e in self.store.edges() if e.edge_id not in self.edges]
        for edge, sample in zip(
            fresh, load_samples(fresh, self.scans, False, self.context), strict=True
        ):
            self.edges[edge.edge_id] = edge
            self.samples[edge.edge_id] = sample

    def group(self, edge_id: str) -> str:
        edge = self.edges[edge_id]
        return edge.log_sha256 or edge.log_path


@dataclass
class BaseSet:
    """Labelled edges from ``--base`` files: trained on, but for a guard set kept apart.

    The guard set (a share of every (log, label), fixed by the seed) is never trained on: a
    new version must not lose accuracy there against the model in use (``promotion.py``).
    """

    edge_ids: list[str]
    samples: list[PairSample]
    labels: NDArray[np.bool_]
    guard_samples: list[PairSample] = field(default_factory=list)
    guard_labels: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    guard_edges: list[Edge] = field(default_factory=list)  # for a model that reads local maps

    @classmethod
    def read(
        cls,
        paths: Sequence[Path],
        guard_fraction: float = 0.0,
        seed: int = 0,
        context: Context | None = None,
    ) -> BaseSet:
        """Reads ``paths``, each pair's sides drawn with ``context`` (None: single scans)."""
        if not paths:
            return cls([], [], np.zeros(0, dtype=bool))
        data = read_labelled(list(paths), progress=False, context=context)
        train, guard = stratified_split(data.labels, data.groups, guard_fraction, seed)
        return cls(
            [data.edges[i].edge_id for i in train],
            [data.samples[i] for i in train],
            data.labels[train],
            [data.samples[i] for i in guard],
            data.labels[guard],
            [data.edges[i] for i in guard],
        )


def training_set(
    store: LabelStore, cache: SampleCache, base: BaseSet, fraction: float, seed: int = 0
) -> TrainingSet:
    """The workspace's labelled edges (split) plus the base edges the workspace did not label."""
    cache.refresh()
    labels = {e: y for e, y in majority_labels(store).items() if e in cache.samples}
    groups = {e: cache.group(e) for e in labels}
    held = held_out_split(store, labels, groups, fraction, seed)
    ids = [e for e in cache.edges if e in labels]  # log order
    rows_ids = ids + [e for e in base.edge_ids if e not in labels]
    base_rows = [i for i, e in enumerate(base.edge_ids) if e not in labels]
    samples = [cache.samples[e] for e in ids] + [base.samples[i] for i in base_rows]
    y = np.array([labels[e] for e in ids] + [bool(base.labels[i]) for i in base_rows], dtype=bool)
    is_held = np.array([e in held for e in ids] + [False] * len(base_rows), dtype=bool)
    return TrainingSet(
        edge_ids=rows_ids,
        samples=samples,
        labels=y,
        train=np.flatnonzero(~is_held).astype(np.int64),
        held_out=np.flatnonzero(is_held).astype(np.int64),
        workspace_labels=len(ids),
    )
