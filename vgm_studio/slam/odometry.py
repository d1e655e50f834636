"""kiss-icp odometry with the log's own odometry as its motion prior.

kiss-icp predicts each frame with a constant-velocity model (``last_pose @ last_delta``). In a
2 m corridor whose walls pin down only one direction, ICP cannot correct a wrong prediction
along the corridor, and at the start of a log (zero velocity) it lags behind: on simulated
corridor loops that alone leaves half the steps centimetres to decimetres off. Wheel
odometry is a far better prediction over one scan, so where the log has it, it replaces the
constant-velocity delta before each frame. ICP then corrects the heading, which wheels get
wrong by degrees; their translation, right to centimetres over a step, stands where ICP would
slide it along walls that pin one direction only (``scan_odometry``'s ``max_slide``).

Without wheels, a log whose scans are far apart (a corrected log thinned to one scan a metre,
Örebro: steps of 1–3 m and up to 76°) defeats the constant-velocity prediction: ICP only pairs
points within 3σ (0.9 m), so it stays where it predicted and every later step inherits the
error. There, every step is searched again against the previous scan by the branch-and-bound
correlative matcher, which converges from metres and tens of degrees off, on a grid of the
surfaces the previous scan saw, not its end points alone (``matching/surface.py``: on end
points, a step of metres scores best short of the truth; Örebro's steps, mean error 1.06 m
→ 0.06 m), and replaces kiss-icp's where it scores clearly higher.

Where a validator is at hand, the best pose of each sector of headings is a candidate unless
another clearly outscores it, and the validator chooses among them: with little overlap a
pose turned the wrong way can put as many points on a few walls as the right one does
(Örebro scan 212: turned −89°, score 0.35, p 0.18; the true −9°, score 0.34, p 0.67). Where
the scores differ clearly, they decide: on so little overlap the validator errs too (Örebro
scan 2: the right pose 0.42, p 0.53; one turned −66°, 0.23, p 0.60). Where the validator
rejects every candidate, its p only ranks failures, and the step that turns least is taken:
between two scans a robot goes on far more often than it turns a quarter turn (scan 212
again, judged by another model of equal accuracy: p 0.028 turned, 0.026 straight on; taking
the turned one left that run's map 0.47 m off, against 0.05).

What it cannot mend: along a featureless or periodic corridor a step a door further scores
as well as the right one, and the validator cannot tell them apart either.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.branch_bound import (
    Hit,
    SearchWindow,
    angular_step,
    branch_and_bound,
    thin_points,
)
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.matcher import MatchResult
from vgm_studio.matching.odometry import KissOdometry, kiss_config
from vgm_studio.matching.refinement import Refinement, refine_with
from vgm_studio.matching.registration import as_3d, pose_to_4x4
from vgm_studio.matching.submap import Submap
from vgm_studio.progress import track


@dataclass(frozen=True)
class Recovery:
    """How a wheel-less kiss-icp step is searched again.

    Attributes:
        linear: Half-width of the search in x and y around the previous scan, metres: the
            widest loop window (3 m); a log with scans farther apart is not one a scan
            matcher can follow without wheels.
        angular_deg: …in heading, degrees. A 180° scanner turned by more than 90° keeps less
            than half of its view, too little to match, so wider would only add false poses.
        gain: The search's step replaces kiss-icp's only if its correlative score (mean
            likelihood of the scan on the previous one) is this much higher, relative
            (``inf``: never searched).
        step_range: The search turns in steps that move a point at this range by one grid
            cell (Cartographer's rule with a nearer "farthest point"): at a scanner's 30 m a
            90° window takes ~1900 steps, three times as many for little gain, since the
            refinement takes the last tenth of a degree.
        sector_deg: With a judge, the window is searched in sectors of headings this wide,
            and each sector's best pose that ``gain`` does not rule out is a candidate (three
            sectors for ±90°: straight on, turned left, turned right).
    """

    linear: float = 3.0
    angular_deg: float = 90.0
    gain: float = 0.1
    step_range: float = 10.0
    sector_deg: float = 60.0

    def __post_init__(self) -> None:
        if not self.sector_deg > 0:
            raise ValueError(f"sector_deg must be positive, not {self.sector_deg}")


@dataclass(frozen=True)
class Judge:
    """A validator choosing among a wheel-less step's candidates.

    Attributes:
        rate: p(success) of each match of a scan (second) against the one before it (first).
        bar: The p at which it accepts a match (a model's threshold). Where no candidate
            reaches it, the step that turns least is taken, whatever the ranks.
    """

    rate: Callable[[Scan, Scan, Sequence[MatchResult]], NDArray[np.float64]]
    bar: float = 0.0


def scan_odometry(
    scans: Sequence[Scan],
    config: MatchConfig | None = None,
    progress: bool = True,
    recovery: Recovery | None = None,
    judge: Judge | None = None,
    on_pose: Callable[[int, NDArray[np.float64]], None] | None = None,
    max_slide: float = 0.0,
) -> NDArray[np.float64]:
    """kiss-icp odometry over scans in order, predicted by the scans' own odometry if any.

    Args:
        scans: The scans in order.
        config: The matcher's settings (range, kiss-icp's, the refinement's).
        progress: Show a progress bar.
        recovery: How a wheel-less step is searched again.
        judge: Chooses among a wheel-less step's candidates; None: the best score.
        on_pose: Told each scan's pose as soon as it is final (index, pose).
        max_slide: With wheels, how far ICP may move the wheels' step, metres
            (``KissOdometry``); it turns the step as it likes. 0: the wheels measure how far
            the robot went, the scans how far it turned. Over one step wheels err by
            centimetres in distance and by degrees in heading; ICP on a map that pins one
            direction only (a corridor, a campus's long walls) slides by decimetres to
            metres. Where it moved the wheels' step by more than 0.2 m the wheels were
            nearer the corrected logs' reference 279 times, ICP 13 times (more than 0.3 m:
            102 to 0; on freiburg-campus 2.3 m, twice); by more than 0.1 m, 883 to 258
            (``benchmarks/wheel_slides.py``).
            Against no limit, with 0 every corrected log with wheels maps as well or better
            (freiburg-campus 0.073 → 0.054 m; 0.064 with 0.2), and Intel 0.0191 → 0.018 m,
            its heading 0.33 → 0.38°.

    Returns:
        (N, 3) sensor poses (x, y, θ) relative to the first scan.
    """
    config = config or MatchConfig()
    recovery = recovery or Recovery()
    wheels = has_wheels(scans)
    pipeline = KissOdometry(kiss_config(config), max_slide=max_slide if wheels else math.inf)
    poses = np.zeros((len(scans), 3))
    previous: Scan | None = None
    bar = track(scans, "odometry", "scan", enabled=progress)
    for i, scan in enumerate(bar):
        if wheels and i > 0:
            delta = se2.between(scans[i - 1].odometry, scan.odometry)  # type: ignore[arg-type]
            pipeline.last_delta = pose_to_4x4(delta)
        pts = scan.points()
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= config.max_range]
        if len(pts) >= 3:
            pipeline.register_frame(as_3d(pts), np.zeros(len(pts)))
            if not wheels and previous is not None and math.isfinite(recovery.gain):
                _recover(pipeline, (previous, scan), pts, poses[i - 1], config, recovery, judge)
            previous = scan
        else:
            # Nothing to register: carry the prediction.
            pipeline.last_pose = pipeline.last_pose @ pipeline.last_delta
        poses[i] = se2.from_matrix(pipeline.last_pose)
        if on_pose is not None:
            on_pose(i, poses[i])
    return poses


def has_wheels(scans: Sequence[Scan]) -> bool:
    """Whether the scans' odometry can predict their steps: every scan has a pose, and not
    all the same one (a log from a robot without encoders may fill its odometry fields with
    zeros, and a prediction that never moves would hold every step still)."""
    if not scans or any(s.odometry is None for s in scans):
        return False
    first = np.asarray(scans[0].odometry)
    return any(not np.array_equal(np.asarray(s.odometry), first) for s in scans[1:])


def _recover(
    pipeline: KissOdometry,
    pair: tuple[Scan, Scan],
    pts: NDArray[np.float64],
    last: NDArray[np.float64],
    config: MatchConfig,
    recovery: Recovery,
    judge: Judge | None,
) -> None:
    """Searches kiss-icp's last step again over a wide window, and restarts kiss-icp's local
    map from the two scans if the search found a clearly better step."""
    previous, current = pair
    step = se2.between(last, se2.from_matrix(pipeline.last_pose))
    submap = Submap.from_scans(
        [previous],
        np.zeros((1, 3)),
        max_range=config.max_range,
        surfaces=True,
        normal_neighbors=config.normal_neighbors,
    )
    # Near the sensor a laser puts several points in a cell: one per two cells scores alike
    # for a third less time (the refinement below uses them all).
    coarse = thin_points(pts, 2 * submap.resolution)
    here = branch_and_bound(submap, coarse, step, SearchWindow(0.0, 0.0))
    bar = (1.0 + recovery.gain) * (here.score if here is not None else 0.0)
    if bar >= 1.0:
        return
    # Only poses that beat kiss-icp's clearly are searched: where it is right, branch and
    # bound prunes nearly everything at the coarse levels.
    turn = angular_step(np.array([[recovery.step_range, 0.0]]), submap.resolution)
    # Around standing still, not around kiss-icp's step: once lost, kiss-icp may carry a wrong
    # speed further than any window, but a scan is rarely more than the window from the last.
    hits = [
        hit
        for centre, window in _sectors(recovery, judge is not None)
        if (hit := branch_and_bound(submap, coarse, centre, window, step=turn, min_score=bar))
    ]
    if not hits:
        return
    # The validator chooses among the sectors' bests that the best does not clearly outscore.
    top = max(hit.score for hit in hits)
    hits = [hit for hit in hits if (1.0 + recovery.gain) * hit.score >= top]
    found = [refine_with(submap.target(), pts, hit.pose, config) for hit in hits]
    best = max(range(len(hits)), key=lambda i: hits[i].score)
    if judge is not None and len(hits) > 1:
        matches = [_judged(submap, pts, hit, r, config) for hit, r in zip(hits, found, strict=True)]
        p = np.asarray(judge.rate(previous, current, matches), dtype=np.float64)
        if len(p) == len(hits) and np.isfinite(p).any():
            p = np.where(np.isfinite(p), p, -np.inf)
            if p.max() >= judge.bar:
                best = int(np.argmax(p))
            else:
                best = int(np.argmin([abs(r.estimate[2]) for r in found]))
    step = found[best].estimate
    pose = pose_to_4x4(se2.compose(last, step))
    # kiss-icp's map holds this scan where it was lost: start it again from the two scans.
    pipeline.local_map.clear()
    pipeline.local_map.update(pipeline.voxelize(as_3d(submap.points))[1], pose_to_4x4(last))
    pipeline.local_map.update(pipeline.voxelize(as_3d(pts))[1], pose)
    pipeline.last_delta = pose_to_4x4(step)
    pipeline.last_pose = pose


def _sectors(recovery: Recovery, split: bool) -> list[tuple[NDArray[np.float64], SearchWindow]]:
    """The recovery window as (centre, window) pairs: whole, or in sectors of headings."""
    half = math.radians(recovery.angular_deg)
    count = max(1, math.ceil(2 * recovery.angular_deg / recovery.sector_deg)) if split else 1
    width = 2 * half / count
    return [
        (np.array([0.0, 0.0, -half + (i + 0.5) * width]), SearchWindow(recovery.linear, width / 2))
        for i in range(count)
    ]


def _judged(
    submap: Submap, pts: NDArray[np.float64], hit: Hit, refined: Refinement, config: MatchConfig
) -> MatchResult:
    """A search's refined pose with the figures a validator reads."""
    fig = refine_with(submap.target(), pts, refined.estimate, config, iterate=False)
    return MatchResult(
        estimate=refined.estimate,
        iterations=refined.iterations,
        converged=refined.converged,
        inlier_ratio=fig.inlier_ratio,
        residual=fig.residual,
        covariance=fig.covariance,
        kiss_estimate=hit.pose,
        score=hit.score,
    )
