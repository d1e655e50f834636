"""When a new version may replace the model in use: only when it cannot be worse.

A version trained on a few labels can score 3 of 3 on three held-out failures while calling
every success a failure. So a version is promoted only when the held-out set can decide (a
minimum of each class), it has an F1 above 0, it is at least as good as the model in use on
the same held-out edges in accuracy and in balanced accuracy, and, where there is a guard set
(the ``--base`` edges' held-out part), it loses no more than a stated margin of the model in
use's accuracy there. The verdict says which rule held it back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.model.metrics import binary_metrics


@dataclass(frozen=True)
class PromotionRule:
    """What a version must show before it replaces the model in use.

    Attributes:
        min_per_class: Held-out edges of each class needed to decide at all.
        guard_margin: Accuracy on the guard set a version may lose against the model in use.
    """

    min_per_class: int = 20
    guard_margin: float = 0.02


@dataclass(frozen=True)
class Scored:
    """A model's p(success) on labelled edges, and the cut it decides at."""

    labels: NDArray[np.bool_]
    p: NDArray[np.float64]
    threshold: float

    def figures(self) -> dict[str, float]:
        """Accuracy, balanced accuracy and F1 (success the positive class)."""
        m = binary_metrics(self.labels, self.p, self.threshold)
        pos, neg = m["tp"] + m["fn"], m["tn"] + m["fp"]
        recall = m["tp"] / pos if pos else math.nan
        specificity = m["tn"] / neg if neg else math.nan
        return {
            "accuracy": float(m["accuracy"]),
            "balanced_accuracy": float(np.nanmean([recall, specificity])),
            "f1": float(m["f1"]),
        }


@dataclass(frozen=True)
class Contest:
    """What a verdict is reached on.

    Attributes:
        new: The version on the held-out edges.
        active: The model in use on the held-out edges it has predictions for (None: no
            model in use, or none of its predictions are of held-out edges).
        active_name: The model in use (``v3``, ``vgmnet-default.pt:…``), if any.
        guard_new: The version on the guard set (None: no guard set).
        guard_active: The model in use on the guard set (None: none, or not loadable).
    """

    new: Scored
    active: Scored | None = None
    active_name: str | None = None
    guard_new: Scored | None = None
    guard_active: Scored | None = None


def verdict(contest: Contest, rule: PromotionRule) -> dict[str, Any]:
    """Promote or not, why, and the figures it was decided on (kept with the version)."""
    new = contest.new.figures()
    out: dict[str, Any] = {"against": contest.active_name, "edges": len(contest.new.labels)}
    out |= {k: new[k] for k in ("accuracy", "balanced_accuracy", "f1")}
    if contest.active is not None:
        old = contest.active.figures()
        out |= {f"active_{k}": v for k, v in old.items()}
    if contest.guard_new is not None:
        out["guard_accuracy"] = contest.guard_new.figures()["accuracy"]
        out["guard_edges"] = len(contest.guard_new.labels)
        if contest.guard_active is not None:
            out["active_guard_accuracy"] = contest.guard_active.figures()["accuracy"]
    reason = _held_back(contest, out, rule)
    return {**out, "promote": reason is None, "reason": reason or _why_promoted(contest)}


def _held_back(contest: Contest, figures: dict[str, Any], rule: PromotionRule) -> str | None:
    """Why the version may not be promoted; None when it may."""
    success = int(contest.new.labels.sum())
    failure = len(contest.new.labels) - success
    if min(success, failure) < rule.min_per_class:
        return (
            f"held-out set too small to decide ({success} success, {failure} failure; "
            f"needs {rule.min_per_class} of each)"
        )
    if not figures["f1"] > 0:
        return "F1 0 on the held-out edges"
    if contest.active is not None:
        for key, name in (("accuracy", "accuracy"), ("balanced_accuracy", "balanced accuracy")):
            if figures[key] < figures[f"active_{key}"]:
                return f"{name} below the model in use's on the held-out edges"
    guard = figures.get("guard_accuracy")
    active_guard = figures.get("active_guard_accuracy")
    if guard is not None and active_guard is not None and guard < active_guard - rule.guard_margin:
        return (
            f"guard-set accuracy {guard:.3f} below the model in use's {active_guard:.3f} "
            f"by more than {rule.guard_margin:g}"
        )
    return None


def _why_promoted(contest: Contest) -> str:
    if contest.active_name is None:
        return "no model in use"
    if contest.active is None:
        return "the model in use has no held-out predictions"
    return "not worse"
