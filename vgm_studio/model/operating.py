"""The operating point SLAM needs: a p(success) cut chosen by the precision it gives.

A false loop costs a pose graph far more than a missed one, so ``slam`` and the studio can
ask for "the cut at which validation precision reaches P" instead of a fixed p(success).
The curve is measured once, on the training run's validation split, and kept in the
checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True)
class PrecisionCurve:
    """Validation precision and recall at every distinct cut, ``success`` the positive class.

    Attributes:
        thresholds: Ascending p(success) cuts: the distinct validation probabilities.
        precision: At each cut, the share of pairs with p ≥ cut that are successes.
        recall: At each cut, the share of successes with p ≥ cut.
    """

    thresholds: list[float]
    precision: list[float]
    recall: list[float]

    def to_dict(self) -> dict[str, list[float]]:
        return {"thresholds": self.thresholds, "precision": self.precision, "recall": self.recall}

    @classmethod
    def from_dict(cls, content: dict[str, list[float]]) -> PrecisionCurve:
        return cls(
            [float(x) for x in content["thresholds"]],
            [float(x) for x in content["precision"]],
            [float(x) for x in content["recall"]],
        )


def precision_curve(labels: ArrayLike, probabilities: ArrayLike) -> PrecisionCurve:
    """Precision and recall of ``p ≥ cut`` for each distinct probability as the cut.

    Tied probabilities share one cut: a pair is never split from its equals.
    """
    y = np.asarray(labels, dtype=bool)
    p = np.asarray(probabilities, dtype=np.float64)
    cuts, inverse = np.unique(p, return_inverse=True)
    # Pairs at or above cut k are those whose distinct value index is ≥ k: suffix sums.
    pos_at = np.bincount(inverse, weights=y, minlength=len(cuts))
    all_at = np.bincount(inverse, minlength=len(cuts))
    tp = np.cumsum(pos_at[::-1])[::-1]
    called = np.cumsum(all_at[::-1])[::-1]
    recall = tp / max(int(y.sum()), 1)
    return PrecisionCurve(cuts.tolist(), (tp / called).tolist(), recall.tolist())


def threshold_for_precision(curve: PrecisionCurve, precision: float) -> float | None:
    """The lowest cut whose validation precision is at least ``precision``; None if none is.

    The lowest such cut keeps the most loops (the highest recall) at that precision.
    """
    reached = np.flatnonzero(np.asarray(curve.precision) >= precision)
    return float(curve.thresholds[reached[0]]) if len(reached) else None
