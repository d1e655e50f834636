"""How a log is read: the options every reader shares, as one typed config."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class ReadOptions:
    """Options for reading a log.

    Attributes:
        poses: What the scan messages' pose fields mean. ``auto`` decides per log: GMapping
            output (``NEFF`` lines, or ``corrected``/``.gfs.`` in the file name) carries reference
            poses, anything else odometry. ``TRUEPOS`` lines always give reference poses.
        fov_deg: Field of view of ``FLASER``/``RLASER`` beams, which carry no angles (see
            ``carmen.flaser_angles`` for the exact convention).
        max_range: Readings at or beyond this are "no return" and not points. ``None`` takes the
            message's own value (ROBOTLASER1, LaserScan) or, for FLASER, 95% of the log's largest
            reading: CARMEN logs mark "no return" with the sensor's saturation value
            (81.91 m for a SICK LMS, ~51 m for a PLS, 32.767 m for others).
        laser: ``front`` reads FLASER/ROBOTLASER1, ``rear`` reads RLASER.
        skip_bad_lines: Read on past malformed lines and count them instead of stopping.
        scan_topic: ROS bags: the LaserScan topic (``None``: the only one in the bag, or
            ``/scan`` among several).
        odom_topic: ROS bags: the Odometry topic (``None``: the only one, if any).
        laser_pose: The laser in the robot's base frame as (x m, y m, yaw degrees); with
            ``laser_flipped`` it overrides what a bag's tf says. ``None``: from tf, else the base.
        laser_flipped: The laser is mounted upside down (its scans are mirrored).
    """

    poses: Literal["auto", "odometry", "reference"] = "auto"
    fov_deg: float = 180.0
    max_range: float | None = None
    laser: Literal["front", "rear"] = "front"
    skip_bad_lines: bool = False
    scan_topic: str | None = None
    odom_topic: str | None = None
    laser_pose: tuple[float, float, float] | None = None
    laser_flipped: bool = False
