"""Where the laser sits on the robot: its pose in the base frame, and whether it is upside down.

Scans are placed in the base frame before anything matches them, so that a scan's pose and
the odometry of the robot are poses of one frame. A laser mounted upside down (rolled or
pitched by π) sees the plane mirrored: its beams turn clockwise where the robot's angles turn
counter-clockwise, so its points are mirrored (y → −y in the laser frame) before the mount's
pose moves them into the base frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2

# A mount closer than this to the base (metres, radians) is the base: edge ids and the
# printed mount stay as they were for a laser at the base.
_SAME = 1e-9


@dataclass(frozen=True)
class LaserMount:
    """The laser's pose in the robot's base frame.

    Attributes:
        x: Metres ahead of the base.
        y: Metres to the left of the base.
        yaw: Heading of the laser's x axis in the base frame, radians.
        flipped: Mounted upside down: the scan is mirrored in 2D.
    """

    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    flipped: bool = False

    @property
    def pose(self) -> NDArray[np.float64]:
        """(x, y, yaw) as an SE(2) pose."""
        return np.array([self.x, self.y, self.yaw], dtype=np.float64)

    @property
    def is_base(self) -> bool:
        """The laser is at the base, facing forward, right side up."""
        return (
            not self.flipped
            and abs(self.x) < _SAME
            and abs(self.y) < _SAME
            and abs(float(se2.wrap_angle(self.yaw))) < _SAME
        )

    def place(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 2) points in the laser frame → the base frame."""
        if self.is_base:
            return points
        pts = points * np.array([1.0, -1.0]) if self.flipped else points
        return se2.transform_points(self.pose, pts)

    def unplace(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 2) points in the base frame → the laser frame (``place`` undone)."""
        if self.is_base:
            return points
        pts = se2.transform_points(se2.inverse(self.pose), points)
        return pts * np.array([1.0, -1.0]) if self.flipped else pts

    def describe(self) -> str:
        """The mount as the options that give it: ``--laser-pose 0.2,0,180 --laser-flipped``."""
        text = f"--laser-pose {self.x:g},{self.y:g},{math.degrees(self.yaw):g}"
        return text + (" --laser-flipped" if self.flipped else "")

    def to_json(self) -> dict[str, Any]:
        return {
            "x": self.x,
            "y": self.y,
            "yaw_deg": math.degrees(self.yaw),
            "flipped": self.flipped,
        }

    def id_text(self) -> str:
        """What an edge id hashes for this mount; empty at the base, so old ids stand."""
        if self.is_base:
            return ""
        flip = ":flipped" if self.flipped else ""
        return f"mount={self.x:.6f},{self.y:.6f},{self.yaw:.6f}{flip}"


def parse_laser_pose(text: str) -> tuple[float, float, float]:
    """``X,Y,YAW`` (metres, metres, degrees) as three finite numbers.

    Raises:
        ValueError: Not three comma-separated finite numbers (the message says so).
    """
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(
            f"{text!r} is not X,Y,YAW: three finite numbers, metres, metres and degrees "
            "(e.g. 0.2,0,180)"
        )
    return values[0], values[1], values[2]


def mount_from_options(
    laser_pose: Sequence[float] | None, laser_flipped: bool
) -> LaserMount | None:
    """The mount the options give (``laser_pose`` as x, y in metres and yaw in degrees)."""
    if laser_pose is None and not laser_flipped:
        return None
    x, y, yaw_deg = (float(v) for v in (laser_pose or (0.0, 0.0, 0.0)))
    return LaserMount(x, y, math.radians(yaw_deg), bool(laser_flipped))


def mount_from_matrix(transform: NDArray[np.float64]) -> LaserMount:
    """The planar mount of a 4×4 transform (laser → base), upside down when its z axis points down.

    The laser's scan plane is its x-y plane; projected on the base's x-y plane, the laser's x
    axis gives the yaw, and its z axis pointing down (roll or pitch near π) mirrors the scan.
    """
    r = transform[:3, :3]
    flipped = bool(r[2, 2] < 0.0)
    # With the mirror taken out, the laser's planar rotation is the base's x axis seen in the
    # scan: its x axis for an upright laser, the same for an upside-down one (roll keeps x).
    yaw = math.atan2(float(r[1, 0]), float(r[0, 0]))
    return LaserMount(float(transform[0, 3]), float(transform[1, 3]), yaw, flipped)
