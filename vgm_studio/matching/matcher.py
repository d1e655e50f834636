"""The scan matcher: kiss-icp from a guess, then 2D refinement, with quality figures."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from kiss_icp.mapping import VoxelHashMap
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.refinement import Refinement, Target, refine_with
from vgm_studio.matching.registration import KissRegistration


@dataclass(frozen=True)
class MatchResult:
    """A match of scan b against scan a.

    Attributes:
        estimate: (x, y, θ) of scan b in the frame of scan a.
        iterations: Refinement iterations (0 when refinement is off or impossible).
        converged: The refinement's steps shrank below its tolerance before the iteration
            limit. It says the optimiser settled, not that the match is right: a match can
            converge onto a wrong alignment, so read it with ``inlier_ratio`` and
            ``kiss_moved``.
        inlier_ratio: Share of scan b's points that agree with scan a after the match.
        residual: RMS point-to-line residual of the inliers, metres.
        covariance: 3×3 covariance of the estimate, None where not available.
        kiss_estimate: kiss-icp's own estimate before refinement.
        kiss_moved: How far kiss-icp moved scan b from the guess, metres. Zero means kiss-icp
            returned the guess unchanged (it found too few correspondences to act on).
        kiss_turned: How far kiss-icp turned scan b from the guess, radians (absolute).
        score: The loop matcher's correlative score (mean likelihood under the points at its
            grid pose, 0..1); None from this pairwise matcher. The loop matcher reports its grid
            pose, and how far that moved and turned from the guess, in the ``kiss_*`` fields.
        spread: The loop matcher's covariance of its score's surface around the estimate
            (``response.response_surface``), in scan a's frame; None where not measured.
        guess_share: The loop matcher's score at the guess over its score at the estimate:
            how much of the match's support the guess keeps; None where not measured.
    """

    estimate: NDArray[np.float64]
    iterations: int
    converged: bool
    inlier_ratio: float
    residual: float
    covariance: NDArray[np.float64] | None
    kiss_estimate: NDArray[np.float64]
    kiss_moved: float = 0.0
    kiss_turned: float = 0.0
    score: float | None = None
    spread: NDArray[np.float64] | None = None
    guess_share: float | None = None

    def figures(self) -> dict[str, Any]:
        """The quality figures as JSON-ready values."""
        # Field by field: ``asdict`` deep-copies every array, once per validated edge.
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d.pop("estimate")
        d.pop("spread")
        d.pop("guess_share")
        for key in ("covariance", "kiss_estimate"):
            if d[key] is not None:
                d[key] = np.asarray(d[key]).tolist()
        d["residual"] = None if not np.isfinite(self.residual) else self.residual
        if self.score is None:
            # Pairwise edges keep the figures they always had.
            d.pop("score")
        return d


class PreparedScan:
    """A scan's points in range and, built on first use, what a match against it needs: its
    refinement target, and kiss-icp's voxel map where it was prepared with a registration. A
    scan only ever matched onto another (a local map's neighbour, a loop's scan) needs its
    points alone.

    Not ``cached_property``: Python 3.11's takes one lock for every instance, and the loop
    threads build their targets at once (two building one is only work twice; the first
    built is kept).
    """

    def __init__(
        self, points: NDArray[np.float64], neighbors: int, kiss: KissRegistration | None = None
    ) -> None:
        self.points = points
        self._neighbors, self._kiss = neighbors, kiss
        # Empty until built, then the one value built first.
        self._voxel_map: list[VoxelHashMap | None] = []
        self._target: list[Target | None] = []

    @property
    def voxel_map(self) -> VoxelHashMap | None:
        if not self._voxel_map:
            assert self._kiss is not None, "prepared without kiss-icp: no voxel map"
            enough = len(self.points) >= 3
            self._voxel_map.append(self._kiss.target_map(self.points) if enough else None)
        return self._voxel_map[0]

    @property
    def target(self) -> Target | None:
        if not self._target:
            enough = len(self.points) >= 3
            self._target.append(Target.build(self.points, self._neighbors) if enough else None)
        return self._target[0]


class PreparedScans:
    """Each scan's ``PreparedScan``, made once and kept until ``forget``.

    Args:
        max_range: Points farther than this are left out, metres.
        neighbors: Nearest points each target point's local line is fitted to.
        kiss: The registration that builds voxel maps; None where none is needed.
    """

    def __init__(self, max_range: float, neighbors: int, kiss: KissRegistration | None = None):
        self._max_range, self._neighbors, self._kiss = max_range, neighbors, kiss
        # Keyed by id(scan); the scan is kept alongside so its id cannot be reused.
        self._cache: dict[int, tuple[Scan, PreparedScan]] = {}

    def __getitem__(self, scan: Scan) -> PreparedScan:
        cached = self._cache.get(id(scan))
        if cached is None:
            pts = scan.points()
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= self._max_range]
            cached = (scan, PreparedScan(pts, self._neighbors, self._kiss))
            self._cache[id(scan)] = cached
        return cached[1]

    def forget(self, scan: Scan) -> None:
        """Drops a scan's prepared structures (for long logs streamed through)."""
        self._cache.pop(id(scan), None)


class ScanMatcher:
    """Matches pairs of scans; each scan's points, voxel map and normals are built once."""

    def __init__(self, config: MatchConfig | None = None) -> None:
        self.config = config or MatchConfig()
        self._kiss = KissRegistration(self.config)
        self._prepared = PreparedScans(
            self.config.max_range, self.config.normal_neighbors, self._kiss
        )

    def points(self, scan: Scan) -> NDArray[np.float64]:
        return self._prepared[scan].points

    def forget(self, scan: Scan) -> None:
        """Drops a scan's cached structures (for long logs streamed through)."""
        self._prepared.forget(scan)

    def judge(self, a: Scan, b: Scan, pose: NDArray[np.float64]) -> Refinement | None:
        """How scan b at ``pose`` (not moved) agrees with scan a; None where either has too
        few points to say."""
        return self.refine(a, b, pose, iterate=False)

    def refine(
        self, a: Scan, b: Scan, guess: NDArray[np.float64], iterate: bool = True
    ) -> Refinement | None:
        """Scan b refined onto scan a from ``guess``, point to line without kiss-icp first (a
        guess already within centimetres); None where either has too few points."""
        pa, pb = self._prepared[a], self._prepared[b]
        if pa.target is None or len(pb.points) < 3:
            return None
        pose = np.asarray(guess, dtype=np.float64)
        return refine_with(pa.target, pb.points, pose, self.config, iterate=iterate)

    def match(self, a: Scan, b: Scan, guess: NDArray[np.float64]) -> MatchResult:
        """Estimates the pose of scan b in the frame of scan a, starting from ``guess``."""
        pa, pb = self._prepared[a], self._prepared[b]
        guess = np.asarray(guess, dtype=np.float64)
        if pa.voxel_map is None or pa.target is None or len(pb.points) < 3:
            return MatchResult(guess, 0, False, 0.0, float("inf"), None, guess)
        kiss = self._kiss.align(pb.points, pa.voxel_map, guess)
        step = se2.between(guess, kiss)
        moved, turned = float(math.hypot(step[0], step[1])), float(abs(step[2]))
        if not self.config.refine:
            r = refine_with(pa.target, pb.points, kiss, self.config, iterate=False)
            return MatchResult(kiss, 0, True, r.inlier_ratio, r.residual, None, kiss, moved, turned)
        r = refine_with(pa.target, pb.points, kiss, self.config)
        return MatchResult(
            r.estimate,
            r.iterations,
            r.converged,
            r.inlier_ratio,
            r.residual,
            r.covariance,
            kiss,
            moved,
            turned,
        )
