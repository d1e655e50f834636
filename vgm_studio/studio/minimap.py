"""Where in the building a pair lies: the whole trajectory, small, with the two scans marked."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.datasets import ScanLog
from vgm_studio.studio.heatmap import BACKGROUND_RGB, PANEL_WIDTH

HEIGHT = 150
_MARGIN = 14
_TRACK_RGB = (110, 110, 110)


@dataclass(frozen=True)
class Trajectory:
    """A log's sensor path and the picture of it without markers.

    Attributes:
        source: ``reference`` or ``odometry``: which poses are drawn.
        poses: (N, 3) one pose per scan.
        base: (HEIGHT, PANEL_WIDTH, 3) RGB of the path alone.
        scale: Pixels per metre.
        origin: World (x, y) at the picture's left-bottom corner (inside the margin).
    """

    source: str
    poses: NDArray[np.float64]
    base: NDArray[np.uint8]
    scale: float
    origin: tuple[float, float]

    def pixel(self, x: float, y: float) -> tuple[int, int]:
        """World metres → picture pixel (+y up)."""
        u = _MARGIN + (x - self.origin[0]) * self.scale
        v = HEIGHT - _MARGIN - (y - self.origin[1]) * self.scale
        return round(u), round(v)


def trajectory(log: ScanLog) -> Trajectory | None:
    """The log's reference path when every scan has one, else its odometry; None without both."""
    for source in ("reference", "odometry"):
        poses = [getattr(scan, source) for scan in log.scans]
        if poses and all(p is not None for p in poses):
            return _drawn(source, np.asarray(poses, dtype=np.float64))
    return None


def _drawn(source: str, poses: NDArray[np.float64]) -> Trajectory:
    lo, hi = poses[:, :2].min(axis=0), poses[:, :2].max(axis=0)
    span = np.maximum(hi - lo, 1e-6)
    scale = float(min((PANEL_WIDTH - 2 * _MARGIN) / span[0], (HEIGHT - 2 * _MARGIN) / span[1]))
    # Centre the path in the picture.
    room = np.array([PANEL_WIDTH - 2 * _MARGIN, HEIGHT - 2 * _MARGIN]) / scale
    origin = (float(lo[0] - (room[0] - span[0]) / 2), float(lo[1] - (room[1] - span[1]) / 2))
    base = np.full((HEIGHT, PANEL_WIDTH, 3), BACKGROUND_RGB, dtype=np.uint8)
    traj = Trajectory(source, poses, base, scale, origin)
    points = np.array([traj.pixel(x, y) for x, y in poses[:, :2]], dtype=np.int32)
    cv2.polylines(base, [points.reshape(-1, 1, 2)], False, _TRACK_RGB, 1, cv2.LINE_AA)
    cv2.putText(
        base, f"trajectory ({source})", (4, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (170, 170, 170), 1
    )
    return traj


def _mark(
    img: NDArray[np.uint8], traj: Trajectory, pose: NDArray[np.float64], rgb: tuple[int, int, int]
) -> None:
    u, v = traj.pixel(pose[0], pose[1])
    tip = (round(u + 12 * np.cos(pose[2])), round(v - 12 * np.sin(pose[2])))
    cv2.line(img, (u, v), tip, rgb, 2, cv2.LINE_AA)
    cv2.circle(img, (u, v), 5, rgb, -1, cv2.LINE_AA)


def minimap(
    traj: Trajectory, a: int, b: int, prev_rgb: tuple[int, int, int], cur_rgb: tuple[int, int, int]
) -> NDArray[np.uint8]:
    """The path with scan ``a`` (previous) and ``b`` (current) marked, in the points' colours."""
    img = traj.base.copy()
    pa, pb = traj.poses[a], traj.poses[b]
    cv2.line(img, traj.pixel(pa[0], pa[1]), traj.pixel(pb[0], pb[1]), (230, 230, 230), 1)
    _mark(img, traj, pb, cur_rgb)
    _mark(img, traj, pa, prev_rgb)
    return img
