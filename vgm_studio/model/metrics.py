"""Binary classification figures, ``success`` being the positive class, as the paper reports."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import binomtest, rankdata

from vgm_studio.core.decision import DEFAULT_THRESHOLD


def roc_auc(labels: ArrayLike, scores: ArrayLike) -> float:
    """Area under the ROC curve: the chance a random positive outranks a random negative.

    Ties count one half (the Mann-Whitney U statistic). NaN when a class is absent.
    """
    y = np.asarray(labels, dtype=bool)
    s = np.asarray(scores, dtype=np.float64)
    pos, neg = int(y.sum()), int((~y).sum())
    if pos == 0 or neg == 0:
        return float("nan")
    ranks = rankdata(s)
    return float((ranks[y].sum() - pos * (pos + 1) / 2) / (pos * neg))


def binary_metrics(
    labels: ArrayLike, probabilities: ArrayLike, threshold: float = DEFAULT_THRESHOLD
) -> dict[str, Any]:
    """Accuracy, precision, recall, F1, ROC AUC and the confusion counts.

    Args:
        labels: True for ``success``.
        probabilities: Predicted p(success).
        threshold: p(success) at or above which a pair is called a success.
    """
    y = np.asarray(labels, dtype=bool)
    p = np.asarray(probabilities, dtype=np.float64)
    pred = p >= threshold
    tp = int((pred & y).sum())
    fp = int((pred & ~y).sum())
    tn = int((~pred & ~y).sum())
    fn = int((~pred & y).sum())
    n = tp + fp + tn + fn
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return {
        "accuracy": (tp + tn) / n if n else float("nan"),
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "auc": roc_auc(y, p),
        "tp": tp,
        "fp": fp,
        "tn": tn,
        "fn": fn,
        "n": n,
    }


@dataclass(frozen=True)
class PairedComparison:
    """Two classifiers judged on the same pairs: where exactly one of them is right.

    Attributes:
        only_first: Pairs the first model gets right and the second wrong.
        only_second: Pairs the second model gets right and the first wrong.
        p_value: Two-sided exact McNemar test: the chance of a split at least this uneven
            among the ``only_first + only_second`` pairs they disagree on, were both models
            equally good (1.0 where they never disagree).
    """

    only_first: int
    only_second: int
    p_value: float


def paired_comparison(first_right: ArrayLike, second_right: ArrayLike) -> PairedComparison:
    """Whether one model's lead over another on the same test pairs is more than chance.

    Accuracy alone cannot tell: on a building of 50 loops, one pair decides a lead of 0.02.
    Only the pairs the two models disagree on carry evidence, and were the models equally
    good each would go either way with even odds (McNemar's exact test).
    """
    a = np.asarray(first_right, dtype=bool)
    b = np.asarray(second_right, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"the models were judged on {a.shape} and {b.shape} pairs")
    only_first, only_second = int((a & ~b).sum()), int((~a & b).sum())
    n = only_first + only_second
    p = 1.0 if n == 0 else float(binomtest(min(only_first, only_second), n, 0.5).pvalue)
    return PairedComparison(only_first, only_second, p)
