"""The orders an annotator can step through a workspace's edges in."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.labels.votes import human_label, is_conflict

__all__ = [
    "RUN_QUEUES",
    "Queue",
    "RunDecisions",
    "Snapshot",
    "human_label",
    "is_conflict",
    "order",
    "run_order",
]


class Queue(str, Enum):
    """Queue choices, as shown in the panel's dropdown."""

    log = "in log order"
    unlabelled = "unlabelled first"
    uncertain = "most uncertain first"
    disagree = "model disagrees with the label"
    conflicts = "conflicts"
    # A SLAM run's decisions (``match["slam"]``, written by ``slam --loops-out`` and
    # ``audit --edges-out``): the dropdown offers these only where edges carry them.
    kept = "kept by the run"
    rejected = "rejected by the run"
    kept_failure = "kept by the run, labelled failure"
    rejected_success = "rejected by the run, labelled success"

    @property
    def slug(self) -> str:
        """The queue's name in a link (``?queue=kept-failure``)."""
        return self.name.replace("_", "-")

    @property
    def of_a_run(self) -> bool:
        """Queues of a SLAM run's decisions."""
        return self in RUN_QUEUES

    @property
    def hands_out_unlabelled(self) -> bool:
        """Queues whose next edge is an unlabelled one, never the one another tab holds."""
        return self in (Queue.unlabelled, Queue.uncertain)


RUN_QUEUES = (Queue.kept, Queue.rejected, Queue.kept_failure, Queue.rejected_success)


@dataclass
class RunDecisions:
    """What a SLAM run decided about a workspace's edges, and what is known of them.

    Attributes:
        kept: edge_id → whether the run that wrote the edge kept it in its graph; only edges
            that carry a run's decisions.
        reference: edge_id → the edge's reference label.
        off: edge_id → metres between the edge's estimate and its reference relative pose.
    """

    kept: dict[str, bool] = field(default_factory=dict)
    reference: dict[str, str] = field(default_factory=dict)
    off: dict[str, float] = field(default_factory=dict)


@dataclass
class Snapshot:
    """What a queue is ordered by, read from the store at one moment.

    Attributes:
        edge_ids: Every edge, in log order.
        labels: edge_id → {annotator: label}.
        predictions: edge_id → the active model's p(success); empty without a model.
        threshold: p(success) at or above which the model says success.
        run: A SLAM run's decisions, where the edges carry them.
    """

    edge_ids: list[str]
    labels: dict[str, dict[str, str]] = field(default_factory=dict)
    predictions: dict[str, float] = field(default_factory=dict)
    threshold: float = DEFAULT_THRESHOLD
    run: RunDecisions = field(default_factory=RunDecisions)

    def label(self, edge_id: str) -> str | None:
        """What the edge is: the annotators' majority label, else its reference label."""
        return human_label(self.labels.get(edge_id, {})) or self.run.reference.get(edge_id)


def run_order(queue: Queue, snap: Snapshot) -> list[str]:
    """The edge ids of one of a run's queues.

    Log order, except the false loops the run kept: the one furthest off its reference
    first (the loop that told the graph the biggest lie), those without a reference last.
    """
    kept = queue in (Queue.kept, Queue.kept_failure)
    out = [e for e in snap.edge_ids if snap.run.kept.get(e) is kept]
    if queue is Queue.kept_failure:
        false = [e for e in out if snap.label(e) == "failure"]
        return sorted(false, key=lambda e: -snap.run.off.get(e, -1.0))
    if queue is Queue.rejected_success:
        return [e for e in out if snap.label(e) == "success"]
    return out


def order(queue: Queue, snap: Snapshot) -> list[str]:
    """The edge ids of ``queue``, in the order they are shown.

    ``uncertain`` without predictions falls back to ``unlabelled`` (log order).
    """
    labelled = [e for e in snap.edge_ids if snap.labels.get(e)]
    unlabelled = [e for e in snap.edge_ids if not snap.labels.get(e)]
    if queue is Queue.log:
        return list(snap.edge_ids)
    if queue.of_a_run:
        return run_order(queue, snap)
    if queue is Queue.unlabelled:
        return unlabelled + labelled
    if queue is Queue.uncertain:
        p = snap.predictions
        if not p:
            return unlabelled + labelled
        # Stable sort: ties (and edges without a prediction, last) stay in log order.
        return (
            sorted(unlabelled, key=lambda e: abs(p[e] - snap.threshold) if e in p else 2.0)
            + labelled
        )
    if queue is Queue.conflicts:
        return [e for e in labelled if is_conflict(snap.labels[e])]
    disagree = []
    for e in labelled:
        label = human_label(snap.labels[e])
        if label is not None and e in snap.predictions:
            says = "success" if snap.predictions[e] >= snap.threshold else "failure"
            if says != label:
                disagree.append(e)
    # Most confident disagreements first: those are the likeliest label mistakes.
    return sorted(disagree, key=lambda e: -abs(snap.predictions[e] - snap.threshold))
