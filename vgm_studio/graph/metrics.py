"""The relation-based metric of Kümmerle et al. (2009), "On measuring the accuracy of SLAM
algorithms": compare relative poses between scan pairs, not absolute poses, so that a map is
not punished twice for one early error."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.relations import MatchedRelation


@dataclass(frozen=True)
class RelationErrors:
    """Mean and standard deviation of the relation errors of one trajectory.

    Attributes:
        trans_mean: Mean translational error, metres.
        trans_std: Its standard deviation, metres.
        rot_mean_deg: Mean rotational error, degrees.
        rot_std_deg: Its standard deviation, degrees.
        n: Relations compared.
    """

    trans_mean: float
    trans_std: float
    rot_mean_deg: float
    rot_std_deg: float
    n: int

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def relation_errors(
    poses: NDArray[np.float64], relations: Sequence[MatchedRelation]
) -> RelationErrors:
    """Errors of ``poses`` (one per scan of the log) against the relations.

    For each relation δ* between scans a and b, with δ = poses[a]⁻¹ ∘ poses[b], the error is
    ε = δ*⁻¹ ∘ δ: its translation's length and its rotation's magnitude.
    """
    if not relations:
        return RelationErrors(math.nan, math.nan, math.nan, math.nan, 0)
    a = np.array([r.a for r in relations])
    b = np.array([r.b for r in relations])
    ref = np.array([r.pose for r in relations], dtype=np.float64)
    est = se2.between(poses[a], poses[b])
    err = se2.between(ref, est)
    trans = np.hypot(err[:, 0], err[:, 1])
    rot = np.degrees(np.abs(err[:, 2]))
    return RelationErrors(
        float(trans.mean()), float(trans.std()), float(rot.mean()), float(rot.std()), len(a)
    )
