"""The orders an annotator can step through a workspace's edges in."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from vgm_studio.core.decision import DEFAULT_THRESHOLD
from vgm_studio.labels.votes import human_label, is_conflict

__all__ = ["Queue", "Snapshot", "human_label", "is_conflict", "order"]


class Queue(str, Enum):
    """Queue choices, as shown in the panel's dropdown."""

    log = "in log order"
    unlabelled = "unlabelled first"
    uncertain = "most uncertain first"
    disagree = "model disagrees with the label"
    conflicts = "conflicts"

    @property
    def hands_out_unlabelled(self) -> bool:
        """Queues whose next edge is an unlabelled one, never the one another tab holds."""
        return self in (Queue.unlabelled, Queue.uncertain)


@dataclass
class Snapshot:
    """What a queue is ordered by, read from the store at one moment.

    Attributes:
        edge_ids: Every edge, in log order.
        labels: edge_id → {annotator: label}.
        predictions: edge_id → the active model's p(success); empty without a model.
        threshold: p(success) at or above which the model says success.
    """

    edge_ids: list[str]
    labels: dict[str, dict[str, str]] = field(default_factory=dict)
    predictions: dict[str, float] = field(default_factory=dict)
    threshold: float = DEFAULT_THRESHOLD


def order(queue: Queue, snap: Snapshot) -> list[str]:
    """The edge ids of ``queue``, in the order they are shown.

    ``uncertain`` without predictions falls back to ``unlabelled`` (log order).
    """
    labelled = [e for e in snap.edge_ids if snap.labels.get(e)]
    unlabelled = [e for e in snap.edge_ids if not snap.labels.get(e)]
    if queue is Queue.log:
        return list(snap.edge_ids)
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
