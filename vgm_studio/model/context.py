"""Submap VGMs: each side of a pair drawn from its scan and a few neighbours in the log.

Two scans of a right loop can share a single wall: their VGM then looks like a wrong match's,
cells that only one scan fills. A scan's neighbours along the path see more of the same
place, so a pair of small local maps shares more than a pair of scans.

Each neighbour is matched to its centre scan, starting from the poses at hand (the log's
reference or odometry in training, the run's odometry in SLAM), and left out unless the
match holds. The poses alone are not enough: on Belgioioso's sparse log the run's odometry is
more than 12° off on one step in ten, and a model trained on well-placed neighbours then
rejects three right loops in four. Matched, the neighbours sit within 2 cm and 0.25° of the
reference (median), wherever the guess came from.

Two local maps can reach where the other side never looked (one walked on west, the other
east): cells filled from one side only, as a wrong match's are. ``covisible`` keeps a
neighbour's points only where the pair's other scan saw (``seen_by``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.core.compiled import kernel
from vgm_studio.datasets import Scan
from vgm_studio.datasets.scans import MIN_VALID_RANGE
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.matcher import ScanMatcher


@dataclass(frozen=True)
class Context:
    """Which neighbours join a scan in its side of the VGM.

    Attributes:
        neighbours: Scans kept on each side of the centre scan (0: the scan alone).
        spacing: A neighbour is kept when it is at least this far (m) from the last kept
            pose, so that each adds a view of its own ...
        turn: ... or has turned at least this much (rad) from it.
        reach: The walk along the log stops after this much path (m) ...
        scans: ... or after this many scans (a robot standing still).
        matched: Match each neighbour to the centre scan, and keep it only where the
            match converged with ``min_inliers`` of its points on the centre's walls; False
            places it by the poses alone.
        min_inliers: See ``matched``.
        covisible: Keep a neighbour's points only where the pair's other scan, placed by
            the match's estimate, saw (``seen_by``); the centre scans are kept whole.
        view_margin: How far (m) beyond the other scan's beam a point still counts as seen.
    """

    neighbours: int = 0
    spacing: float = 0.5
    turn: float = 0.35
    reach: float = 2.0
    scans: int = 400
    matched: bool = True
    min_inliers: float = 0.3
    covisible: bool = False
    # A wall's cells under the matched pose's error; from first principles, not fitted.
    view_margin: float = 0.3


DEFAULT_CONTEXT = Context(neighbours=2, covisible=True)
"""The bundled model's context: what ``vgm-studio train`` draws by default, and the background
trainer always, so that a version can start from the bundled model's weights. Two neighbours a
side, cropped to what the other side saw: ahead of single scans on the leave-one-building-out
table in two draws."""


Poses = Sequence["NDArray[np.float64] | None"] | NDArray[np.float64]
"""Each scan's pose in one frame, by index in the log (None: the log gives none)."""

Placements = dict[tuple[int, int], "NDArray[np.float64] | None"]
"""(centre, neighbour) → the neighbour's pose in the centre's frame (None: its match failed)."""


def log_poses(scans: Sequence[Scan]) -> list[NDArray[np.float64] | None]:
    """The poses a log gives its scans: the reference where it has one, else the odometry."""
    return [s.reference if s.reference is not None else s.odometry for s in scans]


def neighbours(poses: Poses, centre: int, other: int, context: Context) -> list[int]:
    """Indices of the neighbours that join scan ``centre`` (itself not included).

    A neighbour is never nearer (in the log) to ``other``, the pair's other scan, than to
    ``centre``: two sides that shared scans would agree by construction.
    """
    return _short_of(walk(poses, centre, context), centre, other)


def walk(poses: Poses, centre: int, context: Context) -> list[int]:
    """The neighbours scan ``centre`` takes when no other scan of the pair is near it, in
    order. A nearer ``other`` only stops each walk sooner, so the neighbours of any pair are
    this list's scans nearer to ``centre`` than to ``other`` (``neighbours``)."""
    start = poses[centre]
    if context.neighbours <= 0 or start is None:
        return []
    kept: list[int] = []
    for step in (-1, 1):
        last = prev = start
        path = 0.0
        found = 0
        for j in range(centre + step, centre + step * (context.scans + 1), step):
            if not 0 <= j < len(poses):
                break
            pose = poses[j]
            if pose is None:
                break
            path += math.hypot(pose[0] - prev[0], pose[1] - prev[1])
            prev = pose
            if path > context.reach:
                break
            moved = math.hypot(pose[0] - last[0], pose[1] - last[1])
            turned = abs(se2.wrap(float(pose[2] - last[2])))
            if moved >= context.spacing or turned >= context.turn:
                kept.append(j)
                last = pose
                found += 1
                if found == context.neighbours:
                    break
    return sorted(kept)


def _short_of(walked: list[int], centre: int, other: int) -> list[int]:
    return [j for j in walked if abs(j - other) > abs(j - centre)]


def seen_by(scan: Scan, points: NDArray[np.float64], margin: float) -> NDArray[np.bool_]:
    """Which ``points`` (in the scan's base frame) lie where the scan saw them.

    A point is seen when it lies within the laser's field of view and no farther from it
    than the beam at its bearing reached, plus ``margin``; a beam with no return saw free
    space out to the laser's maximum range.
    """
    pts = np.asarray(points, dtype=np.float64)
    if scan.mount is not None:
        pts = scan.mount.unplace(pts)
    # The beam's test in float32, as ``Scan.valid`` reads the ranges.
    limits = np.array([MIN_VALID_RANGE, scan.max_range], np.float32)
    turn = round(2 * math.pi / abs(scan.angle_increment))
    beams = (scan.angle_min, scan.angle_increment, margin)
    seen: NDArray[np.bool_] = _seen(np.ascontiguousarray(pts), scan.ranges, limits, beams, turn)
    return seen


@kernel
def _seen(pts: Any, ranges: Any, limits: Any, beams: Any, turn: int) -> Any:
    """``seen_by``'s test point by point, in numpy's order of operations; an audit asks it
    12,000 times on the Killian Court graph, each for a few hundred points."""
    angle_min, increment, margin = beams
    out = np.empty(len(pts), np.bool_)
    for i in range(len(pts)):
        x, y = pts[i, 0], pts[i, 1]
        bearing = np.arctan2(y, x) - angle_min
        beam = np.rint((np.pi - np.mod(np.pi - bearing, 2.0 * np.pi)) / increment)
        if beam < 0:
            beam += turn
        if not 0 <= beam < len(ranges):
            out[i] = False
            continue
        r = ranges[int(beam)]
        returned = r >= limits[0] and r < limits[1] and np.isfinite(r)
        reach = np.float64(r) if returned else np.float64(limits[1])
        out[i] = np.hypot(x, y) <= reach + margin
    return out


class LocalMapper:
    """Local maps of one log's scans: each scan with its neighbours, in its own frame.

    Args:
        scans: Every scan of the log.
        poses: Every scan's pose, by index (``log_poses``, or a SLAM run's odometry): which
            scans are neighbours, and the guess each is matched from.
        context: Which neighbours, and whether they are matched.
        matcher: Matches a neighbour to its centre (one is made if not given).
    """

    def __init__(
        self,
        scans: Sequence[Scan],
        poses: Poses,
        context: Context,
        matcher: ScanMatcher | None = None,
    ) -> None:
        self.scans = scans
        self.poses = poses
        self.context = context
        self._matcher = matcher
        self._placed: Placements = {}
        self._walks: dict[int, list[int]] = {}
        # A keyframe's map is asked for again by every loop it takes part in.
        self._maps: dict[tuple[int, tuple[int, ...]], NDArray[np.float64]] = {}
        # Each centre's map over its whole walk, and each scan's rows in it: a map that ends
        # short of the pair's other scan (a sequential pair's) is cut from it, not placed again.
        self._whole: dict[int, tuple[NDArray[np.float64], dict[int, slice]]] = {}

    def points(self, centre: int, other: int) -> NDArray[np.float64]:
        """Scan ``centre``'s points and its neighbours' (those that hold), in ``centre``'s
        frame, (N, 2); ``other`` is the pair's other scan (``neighbours``)."""
        walked = self._walks.get(centre)
        if walked is None:
            walked = self._walks[centre] = walk(self.poses, centre, self.context)
        near = tuple(_short_of(walked, centre, other))
        key = (centre, near)
        made = self._maps.get(key)
        if made is None:
            whole, rows = self._whole_walk(centre, walked)
            if len(near) == len(walked):
                made = whole
            else:
                made = np.concatenate([whole[rows[j]] for j in (centre, *near) if j in rows])
            self._maps[key] = made
        return made

    def _whole_walk(
        self, centre: int, walked: list[int]
    ) -> tuple[NDArray[np.float64], dict[int, slice]]:
        """The map of ``centre`` and every neighbour on its walk that holds, and the rows of
        each scan in it."""
        if centre not in self._whole:
            parts, rows, start = [self.scans[centre].points()], {}, 0
            rows[centre] = slice(0, len(parts[0]))
            for j in walked:
                pose = self.placed(centre, j)
                if pose is not None:
                    start += len(parts[-1])
                    parts.append(se2.transform_points(pose, self.scans[j].points()))
                    rows[j] = slice(start, start + len(parts[-1]))
            whole = np.concatenate(parts) if len(parts) > 1 else parts[0]
            self._whole[centre] = (whole, rows)
        return self._whole[centre]

    def sides(
        self, a: int, b: int, estimate: Sequence[float] | NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Both sides of the pair (a, b) with ``estimate`` b's pose in a's frame: each in its
        own scan's frame, cropped to what the other scan saw where ``covisible``."""
        prev, cur = self.points(a, b), self.points(b, a)
        if not self.context.covisible:
            return prev, cur
        pose = np.asarray(estimate, dtype=np.float64)
        scan_a, scan_b = self.scans[a], self.scans[b]
        na, nb = len(scan_a.points()), len(scan_b.points())  # each map starts with its scan
        margin = self.context.view_margin
        # a's neighbours in b's frame against b's view; b's in a's frame against a's view.
        keep_a = seen_by(scan_b, se2.transform_points(se2.inverse(pose), prev[na:]), margin)
        keep_b = seen_by(scan_a, se2.transform_points(pose, cur[nb:]), margin)
        return (
            np.concatenate([prev[:na], prev[na:][keep_a]]),
            np.concatenate([cur[:nb], cur[nb:][keep_b]]),
        )

    @property
    def match_config(self) -> MatchConfig:
        """The settings each neighbour is matched with."""
        return self._matcher.config if self._matcher is not None else MatchConfig()

    def adopt(self, placements: Placements) -> None:
        """Takes placements made elsewhere (``slam/placing.py``) by this mapper's recipe."""
        for key, pose in placements.items():
            self._placed.setdefault(key, pose)

    def placed(self, centre: int, j: int) -> NDArray[np.float64] | None:
        """Scan ``j``'s pose in ``centre``'s frame; None where its match does not hold."""
        key = (centre, j)
        if key not in self._placed:
            guess = se2.between(self.poses[centre], self.poses[j])  # type: ignore[arg-type]
            if not self.context.matched:
                self._placed[key] = guess
            else:
                if self._matcher is None:
                    self._matcher = ScanMatcher()
                match = self._matcher.match(self.scans[centre], self.scans[j], guess)
                holds = match.converged and match.inlier_ratio >= self.context.min_inliers
                self._placed[key] = match.estimate if holds else None
        return self._placed[key]
