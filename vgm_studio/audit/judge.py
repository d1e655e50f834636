"""Each edge of a graph judged from its scans: the pair placed by the edge's own measurement.

The matcher starts once more from the measurement (``Rematch``). A right measurement stays
where it is, to the noise of the two matchers: on MIT's Killian Court graph the median loop
moves 5 cm and 0.4°, a quarter more than 11 cm, since its measurements are coarser than this
project's matcher. The validator was trained to call such a pose a success only within
centimetres, so it reads the pair where the matcher settled when that lies within the
reference labels' failure distance of the measurement (``LabelThresholds.failure_*``):
there the measurement is at worst imprecise, and the question is whether the two scans show
one place. Where the matcher went farther (or failed), it reads the pair at the measurement
itself, with the figures a match there would report: the edge claims that pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.core.cpus import usable_threads
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.matcher import MatchResult, ScanMatcher
from vgm_studio.matching.reference_labels import LabelThresholds
from vgm_studio.model.context import seen_by
from vgm_studio.progress import track


@dataclass(frozen=True)
class Rematch:
    """The matcher's own answer, started from the measurement.

    Attributes:
        moved: How far it moved b from the measurement, metres.
        turned: …and turned it, degrees (absolute).
        inlier_ratio: Share of b's points on a's walls at the matcher's pose.
        converged: The refinement settled.
        match: The match itself.
    """

    moved: float
    turned: float
    inlier_ratio: float
    converged: bool
    match: MatchResult

    def near(self, thresholds: LabelThresholds) -> bool:
        """The matcher settled within the failure distance of the measurement."""
        return (
            self.converged
            and self.moved < thresholds.failure_xy
            and self.turned < thresholds.failure_theta_deg
        )

    def to_json(self) -> dict[str, float | bool]:
        return {
            "moved_m": self.moved,
            "turned_deg": self.turned,
            "inlier_ratio": self.inlier_ratio,
            "converged": self.converged,
        }


def measured(
    matcher: ScanMatcher, a: Scan, b: Scan, measurement: NDArray[np.float64]
) -> MatchResult:
    """The pair at the measurement, with the figures a match there would report."""
    pose = np.asarray(measurement, dtype=np.float64)
    r = matcher.judge(a, b, pose)
    if r is None:
        return MatchResult(pose, 0, False, 0.0, math.inf, None, pose)
    return MatchResult(pose, 0, True, r.inlier_ratio, r.residual, r.covariance, pose)


def rematch(matcher: ScanMatcher, a: Scan, b: Scan, measurement: NDArray[np.float64]) -> Rematch:
    """Matches b to a again, starting from the measurement."""
    m = matcher.match(a, b, measurement)
    step = se2.between(measurement, m.estimate)
    return Rematch(
        moved=float(math.hypot(step[0], step[1])),
        turned=float(abs(math.degrees(step[2]))),
        inlier_ratio=float(m.inlier_ratio),
        converged=bool(m.converged),
        match=m,
    )


def judge_pairs(
    matcher: ScanMatcher,
    scans: Sequence[Scan],
    pairs: Sequence[tuple[int, int, NDArray[np.float64]]],
    thresholds: LabelThresholds,
    progress: bool = True,
) -> tuple[list[MatchResult], list[Rematch]]:
    """For every (a, b, z): the match the validator reads (see the module's docstring), and
    the re-match from z.

    Pairs go to the usable threads: kiss-icp and the refinement's numpy release the GIL.
    """

    def one(pair: tuple[int, int, NDArray[np.float64]]) -> tuple[MatchResult, Rematch]:
        a, b, z = pair
        again = rematch(matcher, scans[a], scans[b], z)
        if again.near(thresholds):
            return again.match, again
        return measured(matcher, scans[a], scans[b], z), again

    # Every scan enters the matcher's cache here, before the threads share it; its voxel map
    # and normals are still built on first use.
    for scan in scans:
        matcher.points(scan)
    threads = usable_threads()
    total, on = len(pairs), progress
    if threads > 1:
        with ThreadPoolExecutor(threads) as pool:
            done = list(
                track(pool.map(one, pairs), "matching edges", "edge", total=total, enabled=on)
            )
    else:
        done = [one(p) for p in track(pairs, "matching edges", "edge", total=total, enabled=on)]
    return [d[0] for d in done], [d[1] for d in done]


def shared_view(a: Scan, b: Scan, estimate: NDArray[np.float64], margin: float) -> float:
    """How much of each scan lies where the other looked, the less of the two (0..1).

    Two 180° scans of one corridor taken facing away from each other share almost nothing:
    the validator, which was trained on pairs a matcher had aligned, calls such a pair a
    failure, though the scans show nothing wrong. On the Killian Court graph 17 of its own
    loops the validator was sure of (p < 0.05) shared no view at all.
    """
    pa, pb = a.points(), b.points()
    if len(pa) == 0 or len(pb) == 0:
        return 0.0
    pose = np.asarray(estimate, dtype=np.float64)
    seen_by_a = seen_by(a, se2.transform_points(pose, pb), margin)
    seen_by_b = seen_by(b, se2.transform_points(se2.inverse(pose), pa), margin)
    return float(min(seen_by_a.mean(), seen_by_b.mean()))
