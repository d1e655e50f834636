"""The loop matcher: an exact correlative search over a window, then point-to-line refinement.

``LoopMatcher`` finds the pose of a scan on a submap of the keyframes around a loop target by
branch-and-bound correlative scan matching (``branch_bound.py``: Olson 2009; Hess et al. 2016)
over a window around the guess, so it converges from metres and tens of degrees off; the
point-to-line refinement (``refinement.py``) against the submap's points then takes the pose from
the grid's centimetres to millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.branch_bound import (
    Hit,
    SearchWindow,
    angular_step,
    branch_and_bound,
    brute_force,
    thin_points,
)
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.matcher import MatchResult, PreparedScans
from vgm_studio.matching.refinement import Target, refine_pose, refine_with
from vgm_studio.matching.response import response_surface, score_at
from vgm_studio.matching.submap import Submap

__all__ = [
    "CorrelativeConfig",
    "Hit",
    "LoopMatcher",
    "SearchWindow",
    "angular_step",
    "branch_and_bound",
    "brute_force",
]


@dataclass(frozen=True)
class CorrelativeConfig:
    """Loop matcher settings.

    Attributes:
        max_range: Readings farther than this are left out, metres.
        angular_step: Angle between searched rotations, radians; None chooses it as
            Cartographer does, so the farthest end point moves at most one cell per step.
        min_score: Poses whose score (mean grid value under the points, 0..1) is below this are
            not searched; when no pose reaches it, the match fails. Raising it prunes harder.
        thin: Scan points closer than this to an already kept one are left out of the search
            (not of the refinement), metres; 0 keeps all. Near the sensor a laser puts several
            points per cell, which add time and weight but no information.
        refine: Run the point-to-line refinement against the submap's points.
        match: The refinement's settings (iterations, gates, inlier distance, degeneracy), the
            same as the pairwise matcher's.
        spread_temperature: τ of the score surface's covariance around the match
            (``response.response_surface``), in points; None: not measured. The graph
            adds it to the refinement's covariance (``slam.factors.matcher_covariance``).
            3: with 1, Olson's independent points, every row was as good or worse (Örebro
            0.056 → 0.060 m, the infinite corridor 0.047 → 0.050).
        spread_linear: Half-width of the translations it samples, metres.
        spread_angular_deg: Half-width of the headings it samples, degrees.
    """

    max_range: float = 30.0
    angular_step: float | None = None
    min_score: float = 0.0
    thin: float = 0.0
    refine: bool = True
    match: MatchConfig = field(default_factory=MatchConfig)
    spread_temperature: float | None = 3.0
    spread_linear: float = 0.5
    spread_angular_deg: float = 3.0


class LoopMatcher:
    """Branch-and-bound correlative matcher (Olson 2009 / Hess et al. 2016) over a window, then
    the existing point-to-line refinement (``refinement.py``) for the final centimetres.

    The figures (inlier ratio, residual, covariance) are those of the refined estimate against
    the target keyframe alone, computed as the pairwise ``ScanMatcher`` computes them, because
    the VGM is built from that pair and the validators were trained on pairwise figures.
    """

    def __init__(self, config: CorrelativeConfig | None = None) -> None:
        self.config = config or CorrelativeConfig()
        self._prepared = PreparedScans(self.config.max_range, self.config.match.normal_neighbors)

    def points(self, scan: Scan) -> NDArray[np.float64]:
        """The scan's points in range, cut once: a keyframe is matched many times."""
        return self._prepared[scan].points

    def _target(self, scan: Scan) -> Target | None:
        return self._prepared[scan].target

    def forget(self, scan: Scan) -> None:
        """Drops a target scan's cached structures (for long logs streamed through)."""
        self._prepared.forget(scan)

    def search(
        self,
        submap: Submap,
        scan: Scan,
        guess: NDArray[np.float64],
        window: SearchWindow,
        min_score: float | None = None,
    ) -> Hit | None:
        """The correlative step alone: the best grid pose of ``scan`` within the window.

        ``min_score`` overrides the config's for this search (the matcher is shared by
        threads, so it is passed, never set).
        """
        pts = thin_points(self.points(scan), self.config.thin)
        return branch_and_bound(
            submap,
            pts,
            np.asarray(guess, np.float64),
            window,
            step=self.config.angular_step,
            min_score=self.config.min_score if min_score is None else min_score,
        )

    def match(
        self,
        submap: Submap,
        target: Scan,
        scan: Scan,
        guess: NDArray[np.float64],
        window: SearchWindow,
        min_score: float | None = None,
    ) -> MatchResult:
        """Estimates the pose of ``scan`` in the submap's frame (the target keyframe's).

        Safe to call from several threads at once: the heavy numpy work releases the GIL.

        Args:
            submap: The grid around the target, in the target keyframe's frame.
            target: The target keyframe itself: the figures are computed against it.
            scan: The scan to place.
            guess: Where the estimate puts ``scan`` in the submap frame; the window's centre.
            window: How far from the guess to search.
            min_score: Overrides ``config.min_score`` for this match.
        """
        guess = np.asarray(guess, dtype=np.float64)
        pts = self.points(scan)
        hit = self.search(submap, scan, guess, window, min_score) if len(pts) >= 3 else None
        tgt = self._target(target)
        if hit is None or tgt is None:
            return MatchResult(guess, 0, False, 0.0, float("inf"), None, guess)
        m = self.config.match
        estimate, iterations, converged = hit.pose, 0, True
        if self.config.refine:
            estimate, iterations, converged = refine_pose(submap.target(), pts, hit.pose, m)
        fig = refine_with(tgt, pts, estimate, m, iterate=False)
        step = se2.between(guess, hit.pose)
        spread, guess_share = self._surface(submap, pts, estimate, guess)
        return MatchResult(
            estimate=estimate,
            iterations=iterations,
            converged=converged,
            inlier_ratio=fig.inlier_ratio,
            residual=fig.residual,
            covariance=fig.covariance,
            kiss_estimate=hit.pose,
            kiss_moved=float(math.hypot(step[0], step[1])),
            kiss_turned=float(abs(step[2])),
            score=hit.score,
            spread=spread,
            guess_share=guess_share,
        )

    def _surface(
        self,
        submap: Submap,
        points: NDArray[np.float64],
        estimate: NDArray[np.float64],
        guess: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64] | None, float | None]:
        """The spread of the score's surface around the estimate, and the share of its score
        the guess keeps; (None, None) where not measured."""
        c = self.config
        if c.spread_temperature is None:
            return None, None
        angular = math.radians(c.spread_angular_deg)
        found = response_surface(
            submap, points, estimate, c.spread_linear, angular, c.spread_temperature
        )
        at_estimate = found.score
        share = score_at(submap, points, guess) / at_estimate if at_estimate > 0 else None
        return found.covariance, share
