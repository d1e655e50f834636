"""Submap VGMs: each side of a pair drawn from its scan and a few neighbours in the log.

Two scans of a right loop can share a single wall: their VGM then looks like a wrong match's,
cells that only one scan fills. A scan's neighbours along the path see more of the same
place, so a pair of small local maps shares more than a pair of scans. A neighbour is placed
by the log's reference pose where it has one, else by its odometry; over a metre or two of
path either is good to a few centimetres on the logs here, as SLAM's own local chain is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets import Scan


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
    """

    neighbours: int = 0
    spacing: float = 0.5
    turn: float = 0.35
    reach: float = 2.0
    scans: int = 400


Poses = Sequence["NDArray[np.float64] | None"] | NDArray[np.float64]
"""Each scan's pose in one frame, by index in the log (None: the log gives none)."""


def log_poses(scans: Sequence[Scan]) -> list[NDArray[np.float64] | None]:
    """The poses a log gives its scans: the reference where it has one, else the odometry."""
    return [s.reference if s.reference is not None else s.odometry for s in scans]


def neighbours(poses: Poses, centre: int, other: int, context: Context) -> list[int]:
    """Indices of the neighbours that join scan ``centre`` (itself not included).

    A neighbour is never nearer (in the log) to ``other``, the pair's other scan, than to
    ``centre``: two sides that shared scans would agree by construction.
    """
    start = poses[centre]
    if context.neighbours <= 0 or start is None:
        return []
    kept: list[int] = []
    for step in (-1, 1):
        last = prev = start
        path = 0.0
        found = 0
        for j in range(centre + step, centre + step * (context.scans + 1), step):
            if not 0 <= j < len(poses) or abs(j - other) <= abs(j - centre):
                break
            pose = poses[j]
            if pose is None:
                break
            path += math.hypot(pose[0] - prev[0], pose[1] - prev[1])
            prev = pose
            if path > context.reach:
                break
            moved = math.hypot(pose[0] - last[0], pose[1] - last[1])
            turned = abs(float(se2.wrap_angle(pose[2] - last[2])))
            if moved >= context.spacing or turned >= context.turn:
                kept.append(j)
                last = pose
                found += 1
                if found == context.neighbours:
                    break
    return sorted(kept)


def local_points(
    scans: Sequence[Scan], poses: Poses, centre: int, other: int, context: Context
) -> NDArray[np.float64]:
    """Scan ``centre``'s points and its neighbours', all in ``centre``'s frame, (N, 2)."""
    points = scans[centre].points()
    near = neighbours(poses, centre, other, context)
    if not near:
        return points
    origin = se2.inverse(poses[centre])  # type: ignore[arg-type]
    parts = [points]
    for j in near:
        placed = se2.compose(origin, poses[j])  # type: ignore[arg-type]
        parts.append(se2.transform_points(placed, scans[j].points()))
    return np.concatenate(parts)
