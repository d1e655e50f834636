"""The relation-based metric of Kümmerle et al. (2009), "On measuring the accuracy of SLAM
algorithms": compare relative poses between scan pairs, not absolute poses, so that a map is
not punished twice for one early error."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

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


@dataclass(frozen=True)
class RelationSampling:
    """How relations are drawn from reference poses (Kümmerle et al. 2009's protocol).

    Their relations join consecutive places and places the robot revisits a few metres apart,
    so a map is scored both on its local shape and on how well its loops close.

    Attributes:
        spacing: Places are reference poses at least this far apart along the path, metres.
        spacing_deg: …or turned this much, degrees.
        near: Pairs of places within this distance are candidates for revisit relations, metres.
        near_per_sequential: Revisit relations drawn per sequential one (at most all there are).
        seed: Seeds the draw.
    """

    spacing: float = 0.5
    spacing_deg: float = 20.0
    near: float = 3.0
    near_per_sequential: float = 1.0
    seed: int = 0


def reference_relations(
    reference: Sequence[NDArray[np.float64] | None], sampling: RelationSampling | None = None
) -> list[MatchedRelation]:
    """Relations between scans made from their reference poses.

    Args:
        reference: Per scan of the log its reference pose, None where it has none.
        sampling: Spacing, neighbourhood and seed.

    Returns:
        Sequential pairs of places, then revisit pairs (within ``near`` metres, not
        consecutive) drawn with the seed; ``line`` is 0 (they come from no file).
    """
    sampling = sampling or RelationSampling()
    scans = np.array([i for i, r in enumerate(reference) if r is not None], dtype=np.int64)
    if len(scans) < 2:
        return []
    poses = np.array([reference[i] for i in scans], dtype=np.float64)
    places = _places(poses, sampling)
    pairs = [(int(a), int(b)) for a, b in itertools.pairwise(places)]
    close = cKDTree(poses[places, :2]).query_pairs(sampling.near, output_type="ndarray")
    close = close[np.abs(close[:, 0] - close[:, 1]) > 1]
    want = min(len(close), round(sampling.near_per_sequential * len(pairs)))
    pick = np.random.default_rng(sampling.seed).choice(len(close), want, replace=False)
    pairs += [(int(places[min(i, j)]), int(places[max(i, j)])) for i, j in close[np.sort(pick)]]
    return [
        MatchedRelation(int(scans[a]), int(scans[b]), se2.between(poses[a], poses[b]), 0)
        for a, b in pairs
    ]


def _places(poses: NDArray[np.float64], sampling: RelationSampling) -> NDArray[np.int64]:
    # A dense reference (TRUEPOS on every scan) would otherwise give thousands of relations a
    # few millimetres long, which measure the noise of the reference, not the map.
    keep = [0]
    turn = math.radians(sampling.spacing_deg)
    for i in range(1, len(poses)):
        d = se2.between(poses[keep[-1]], poses[i])
        if math.hypot(d[0], d[1]) >= sampling.spacing or abs(d[2]) >= turn:
            keep.append(i)
    return np.asarray(keep, dtype=np.int64)
