"""The scan and log types every reader returns and every later stage reads."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.mount import LaserMount

PoseSource = Literal["odometry", "reference"]

# Readings this short are dropouts, not obstacles.
MIN_VALID_RANGE = 0.01


@dataclass(frozen=True)
class Scan:
    """One 2D laser scan with the sensor poses a log gives for it.

    Poses are of the scan's frame in the world as (x, y, θ): the robot's base when ``mount``
    is set (``points`` are placed in the base frame), else the laser's. Ranges at or beyond
    ``max_range`` (the sensor's "no return" value) and below ``MIN_VALID_RANGE`` are not points.
    """

    index: int
    timestamp: float
    ranges: NDArray[np.float32]
    angle_min: float
    angle_increment: float
    max_range: float
    odometry: NDArray[np.float64] | None = None
    reference: NDArray[np.float64] | None = None
    line: int = 0
    mount: LaserMount | None = None
    keep_points: bool = False
    # ``points()`` once computed, where ``keep_points``: SLAM asks for a keyframe's points
    # again for every loop candidate, trail and validation it takes part in (100,000 times on
    # Intel). Only keyframes keep them: points for every scan of a long log would take five
    # times the memory of its ranges. Not pickled.
    _points: list[NDArray[np.float64]] = field(
        default_factory=list, init=False, repr=False, compare=False
    )

    @property
    def num_beams(self) -> int:
        return int(self.ranges.shape[0])

    @property
    def fov(self) -> float:
        """Angle from the first beam to the last, in radians."""
        return self.angle_increment * max(self.num_beams - 1, 0)

    def angles(self) -> NDArray[np.float64]:
        return self.angle_min + self.angle_increment * np.arange(self.num_beams, dtype=np.float64)

    def valid(self) -> NDArray[np.bool_]:
        """Which beams returned a point: in range and finite."""
        # Compare in float32, as ranges are stored: a no-return written as exactly max_range
        # must not come back as a point 1e-7 m short of it.
        r32 = self.ranges
        return (r32 >= MIN_VALID_RANGE) & (r32 < np.float32(self.max_range)) & np.isfinite(r32)

    def points(self) -> NDArray[np.float64]:
        """Returns the (N, 2) valid end points in the base frame (the laser's without a mount);
        read-only where the scan keeps them (``keep_points``), since they are shared."""
        if self._points:
            return self._points[0]
        keep = self.valid()
        r, a = self.ranges[keep].astype(np.float64), self.angles()[keep]
        points = np.stack([r * np.cos(a), r * np.sin(a)], axis=1).astype(np.float64)
        placed = points if self.mount is None else self.mount.place(points)
        if self.keep_points:
            placed.setflags(write=False)
            self._points.append(placed)
        return placed

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_points"] = []
        return state


@dataclass
class ScanLog:
    """All scans of one log plus what the reader learnt about it.

    Attributes:
        pose_source: What the scan messages' pose fields hold.
        reference_origin: Where reference poses come from (``pose fields``, ``TRUEPOS``, or a
            reference log's path), None without any.
        skipped_lines: How many malformed lines ``skip_bad_lines`` read past.
        skipped_line_numbers: Their line numbers, in file order.
        mount: The laser's mount its scans are placed by, None for a laser at the base.
        mount_source: Where the mount came from (``/tf_static``, ``--laser-pose`` …).
        warnings: What the reader chose that a person should hear about (one line each),
            such as which of a bag's LaserScan topics it read.
        declared_mount: The mount a CARMEN log declares in its PARAM lines and where (not yet
            applied: ``open_log`` applies it unless ``--laser-pose`` gives another).
    """

    path: Path
    format: str
    scans: list[Scan]
    content_hash: str
    pose_source: PoseSource | None = None
    reference_origin: str | None = None
    skipped_lines: int = 0
    skipped_line_numbers: list[int] = field(default_factory=list)
    ignored_messages: dict[str, int] = field(default_factory=dict)
    message_counts: dict[str, int] = field(default_factory=dict)
    mount: LaserMount | None = None
    mount_source: str | None = None
    declared_mount: tuple[LaserMount, str] | None = None
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.scans)

    @property
    def timestamps(self) -> NDArray[np.float64]:
        return np.array([s.timestamp for s in self.scans], dtype=np.float64)

    @property
    def has_odometry(self) -> bool:
        return bool(self.scans) and all(s.odometry is not None for s in self.scans)

    @property
    def has_reference(self) -> bool:
        return bool(self.scans) and all(s.reference is not None for s in self.scans)

    def odometry_poses(self) -> NDArray[np.float64] | None:
        """(N, 3) odometry poses, or None when any scan lacks one."""
        if not self.has_odometry:
            return None
        return np.array([s.odometry for s in self.scans], dtype=np.float64)

    def reference_poses(self) -> NDArray[np.float64] | None:
        """(N, 3) reference poses, or None when any scan lacks one."""
        if not self.has_reference:
            return None
        return np.array([s.reference for s in self.scans], dtype=np.float64)

    def travelled_distance(self) -> float:
        """Path length of the reference trajectory, else of odometry, in metres."""
        poses = self.reference_poses()
        if poses is None:
            poses = self.odometry_poses()
        if poses is None or len(poses) < 2:
            return 0.0
        return float(np.sum(np.hypot(*np.diff(poses[:, :2], axis=0).T)))

    def relative_reference(self, a: int, b: int) -> NDArray[np.float64] | None:
        """Reference pose of scan b in the frame of scan a, when both are known."""
        ra, rb = self.scans[a].reference, self.scans[b].reference
        if ra is None or rb is None:
            return None
        return se2.between(ra, rb)


def with_mount(
    log: ScanLog, mount: LaserMount | None, source: str, poses_of_laser: bool
) -> ScanLog:
    """The log with every scan placed in the base frame by ``mount``.

    Args:
        log: The log as read.
        mount: The laser's mount; None leaves the log as it is.
        source: Where the mount came from (``/tf_static``, ``--laser-pose`` …), for ``info``.
        poses_of_laser: The log's poses are of the laser (CARMEN's pose fields), so they are
            moved to the base (pose ∘ mount⁻¹) and the world stays where the log put it. ROS
            odometry is of the base already and stays.
    """
    if mount is None:
        return log
    back = se2.inverse(mount.pose)

    def to_base(pose: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
        if pose is None or not poses_of_laser:
            return pose
        return se2.compose(pose, back)

    scans = [
        replace(s, mount=mount, odometry=to_base(s.odometry), reference=to_base(s.reference))
        for s in log.scans
    ]
    return replace(log, scans=scans, mount=mount, mount_source=source)


def mount_line(log: ScanLog) -> str:
    """The mount a log's scans are placed by, and where it came from, for people to read."""
    source = log.mount_source or "no tf in this log and no --laser-pose"
    if log.mount is None:
        return f"at the base ({source})"
    return f"{log.mount.describe()} ({source})"
