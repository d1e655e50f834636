"""ROS bags: ``sensor_msgs/LaserScan`` scans with ``nav_msgs/Odometry`` poses.

Reads, with the ``rosbags`` library and without a ROS installation:

* ROS 1 bags: one ``.bag`` file (format ``rosbag1``);
* ROS 2 bags: a folder holding ``metadata.yaml`` and sqlite3 (``.db3``) or mcap storage, or one
  such storage file on its own (format ``rosbag2``).

Topics: the scans come from ``ReadOptions.scan_topic``, or from the bag's only LaserScan topic,
or, of several, from ``/scan`` (ROS's usual name; a warning says so and names the others).
Odometry is optional and comes from ``ReadOptions.odom_topic``, or from the bag's only Odometry
topic when it has one. Other topics are not read; their message counts go to
``ScanLog.ignored_messages``.

Times: a message's time is its header stamp, or the time the bag recorded it when the stamp is
zero (drivers that never fill it in).

Poses: a scan's odometry is the Odometry pose ``(x, y, yaw)`` interpolated at the scan's time,
linearly in x, y and the unwrapped yaw. A scan before the first or after the last Odometry
message takes the nearest one if it is at most ``MAX_ODOMETRY_EXTRAPOLATION`` seconds away, and
no odometry otherwise. The Odometry pose is of the robot base (its ``child_frame_id``).

The laser's mount: ``ReadOptions.laser_pose``/``laser_flipped`` when given; else the chain of
``/tf_static`` and ``/tf`` from the LaserScan's ``frame_id`` to the Odometry's
``child_frame_id`` (``datasets/tf.py``); else the laser is taken to be at the base. Scans carry
the mount, and ``Scan.points`` places their points in the base frame.

Readings: ``ranges`` are kept as the bag has them, NaN and ±inf included; ``Scan.points`` drops
those, readings below ``MIN_VALID_RANGE`` and readings at or beyond ``max_range``
(``ReadOptions.max_range``, else the message's ``range_max``).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from vgm_studio.core.hashing import content_hash
from vgm_studio.core.se2 import wrap_angle
from vgm_studio.datasets.bag_errors import BAG_ERRORS, bag_error, one_line
from vgm_studio.datasets.bag_topics import (
    ODOMETRY,
    SCANS,
    choose_topic,
)
from vgm_studio.datasets.mount import LaserMount, mount_from_options
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.scans import Scan, ScanLog
from vgm_studio.datasets.tf import TF_TYPES, TfTree, mount_from_tf
from vgm_studio.errors import InputError
from vgm_studio.progress import counter

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

ROS2_STORAGE_SUFFIXES = frozenset({".db3", ".mcap"})


# Seconds a scan may lie before the first or after the last Odometry message and still take it.
MAX_ODOMETRY_EXTRAPOLATION = 0.5


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Rotation about z of a quaternion, in (−π, π]."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def interpolate_odometry(
    times: NDArray[np.float64],
    stamps: NDArray[np.float64],
    poses: NDArray[np.float64],
    max_extrapolation: float = MAX_ODOMETRY_EXTRAPOLATION,
) -> NDArray[np.float64]:
    """Poses (x, y, yaw) at ``times`` from poses at increasing ``stamps``.

    Linear in x, y and unwrapped yaw inside the stamps' span; the nearest pose outside it, up to
    ``max_extrapolation`` seconds away. Rows for times farther out are NaN.
    """
    out = np.full((len(times), 3), np.nan)
    if len(stamps) == 0:
        return out
    yaw = np.unwrap(poses[:, 2])
    out[:, 0] = np.interp(times, stamps, poses[:, 0])
    out[:, 1] = np.interp(times, stamps, poses[:, 1])
    out[:, 2] = wrap_angle(np.interp(times, stamps, yaw))
    outside = np.maximum(stamps[0] - times, times - stamps[-1])
    out[outside > max_extrapolation] = np.nan
    return out


@dataclass
class _RawScan:
    stamp_ns: int
    ranges: NDArray[np.float32]
    angle_min: float
    angle_increment: float
    range_max: float


def _stamp_ns(msg: Any, receive_ns: int) -> int:
    stamp = msg.header.stamp
    ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return ns if ns != 0 else int(receive_ns)


def _messages(
    path: Path, reader: AnyReader, connections: Sequence[Connection], total: int
) -> Iterator[tuple[Connection, int, Any]]:
    """Deserialised messages in bag order, with a progress bar; rosbags' errors as InputError."""
    raw_messages = reader.messages(connections=connections)
    with counter(total, path.name, "message") as bar:
        while True:
            try:
                connection, receive_ns, data = next(raw_messages)
            except StopIteration:
                return
            except BAG_ERRORS as err:
                raise bag_error(path, err) from None
            try:
                msg = reader.deserialize(data, connection.msgtype)
            except BAG_ERRORS as err:
                raise InputError(
                    path,
                    f"{connection.topic}: cannot decode the {connection.msgtype} message "
                    f"recorded at {receive_ns / 1e9:.9f} s: {one_line(err)}",
                ) from None
            bar.update()
            yield connection, receive_ns, msg


def _open_reader(path: Path, is_ros1: bool) -> AnyReader:
    store = Stores.ROS1_NOETIC if is_ros1 else Stores.ROS2_HUMBLE
    try:
        reader = AnyReader([path], default_typestore=get_typestore(store))
        reader.open()
    except BAG_ERRORS as err:
        raise bag_error(path, err) from None
    return reader


def _check_path(path: Path) -> bool:
    """Raises unless ``path`` can be a bag; returns whether it is a ROS 1 bag."""
    if not path.exists():
        raise InputError(path, "no such file or folder")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise InputError(path, "not a ROS 2 bag folder (it has no metadata.yaml)")
        return False
    if path.suffix == ".bag":
        return True
    if path.suffix in ROS2_STORAGE_SUFFIXES:
        return False
    raise InputError(
        path, "not a ROS bag: expected a .bag file, a ROS 2 bag folder, or a .db3/.mcap file"
    )


@dataclass
class _Collected:
    """What the reader keeps of the messages, in bag order."""

    raw: list[_RawScan] = field(default_factory=list)
    odom_ns: list[int] = field(default_factory=list)
    odom_poses: list[tuple[float, float, float]] = field(default_factory=list)
    counts: Counter[str] = field(default_factory=Counter)
    laser_frame: str = ""
    base_frame: str | None = None
    tf: TfTree = field(default_factory=TfTree)

    def add(self, topic: str, msgtype: str, receive_ns: int, msg: Any, scan_topic: str) -> None:
        self.counts[topic] += 1
        if topic == scan_topic:
            self.laser_frame = self.laser_frame or str(msg.header.frame_id)
            self.raw.append(
                _RawScan(
                    stamp_ns=_stamp_ns(msg, receive_ns),
                    ranges=np.array(msg.ranges, dtype=np.float32),
                    angle_min=float(msg.angle_min),
                    angle_increment=float(msg.angle_increment),
                    range_max=float(msg.range_max),
                )
            )
        elif msgtype in TF_TYPES:
            self.tf.add_message(msg, receive_ns, static=topic.endswith("tf_static"))
        else:
            q = msg.pose.pose.orientation
            pose = (
                float(msg.pose.pose.position.x),
                float(msg.pose.pose.position.y),
                yaw_from_quaternion(float(q.x), float(q.y), float(q.z), float(q.w)),
            )
            if all(math.isfinite(v) for v in pose):
                self.base_frame = self.base_frame or str(msg.child_frame_id) or None
                self.odom_ns.append(_stamp_ns(msg, receive_ns))
                self.odom_poses.append(pose)


def _read_messages(
    path: Path, reader: AnyReader, options: ReadOptions, warnings: list[str]
) -> tuple[_Collected, str]:
    """Reads the scan, odometry and (without a mount in the options) tf topics; what a person
    should hear about the choice of topics goes to ``warnings``."""
    try:
        topics = reader.topics
    except BAG_ERRORS as err:
        raise bag_error(path, err) from None
    scan_topic = choose_topic(path, topics, SCANS, options.scan_topic, warnings)
    assert scan_topic is not None  # required
    odom_topic = choose_topic(path, topics, ODOMETRY, options.odom_topic, warnings)
    read = {t for t in (scan_topic, odom_topic) if t is not None}
    if mount_from_options(options.laser_pose, options.laser_flipped) is None:
        read |= {name for name, info in topics.items() if info.msgtype in TF_TYPES}
    connections = [c for c in reader.connections if c.topic in read]
    total = sum(topics[t].msgcount for t in read)
    got = _Collected()
    for connection, receive_ns, msg in _messages(path, reader, connections, total):
        got.add(connection.topic, connection.msgtype, receive_ns, msg, scan_topic)
    return got, scan_topic


def read_rosbag(path: str | Path, options: ReadOptions | None = None) -> ScanLog:
    """Reads the laser scans, with odometry where the bag has it, from a ROS 1 or ROS 2 bag.

    Args:
        path: A ROS 1 ``.bag`` file, a ROS 2 bag folder, or a ROS 2 ``.db3``/``.mcap`` file.
        options: How to read it; ``scan_topic``, ``odom_topic``, ``max_range``, ``laser_pose``
            and ``laser_flipped`` apply.

    Returns:
        The scans in the order the bag recorded them, placed in the base frame by the laser's
        mount. Poses are in ``Scan.odometry`` (see the module docstring).

    Raises:
        InputError: The path is missing or not a bag, the bag cannot be read, the topic to read
            is missing or ambiguous, or the scan topic holds no messages.
    """
    path = Path(path)
    options = options or ReadOptions()
    is_ros1 = _check_path(path)
    reader = _open_reader(path, is_ros1)
    warnings: list[str] = []
    try:
        got, scan_topic = _read_messages(path, reader, options, warnings)
        topics = reader.topics
    finally:
        with suppress(*BAG_ERRORS):
            reader.close()
    if not got.raw:
        raise InputError(path, f"no messages on the LaserScan topic {scan_topic}")
    mounts, mount_source = _mounts(got, options)
    odometry = _odometry_at_scans(got.raw, got.odom_ns, got.odom_poses)
    scans = [
        Scan(
            index=i,
            timestamp=r.stamp_ns / 1e9,
            ranges=r.ranges,
            angle_min=r.angle_min,
            angle_increment=r.angle_increment,
            max_range=float(options.max_range or _usable_range_max(r)),
            odometry=None if np.isnan(odometry[i]).any() else odometry[i],
            reference=None,
            line=0,
            mount=None if mounts is None or mounts[i].is_base else mounts[i],
        )
        for i, r in enumerate(got.raw)
    ]
    return ScanLog(
        path=path,
        format="rosbag1" if is_ros1 else "rosbag2",
        scans=scans,
        content_hash=content_hash(path),
        pose_source="odometry" if any(s.odometry is not None for s in scans) else None,
        ignored_messages={n: i.msgcount for n, i in topics.items() if n not in got.counts},
        message_counts=dict(got.counts),
        mount=scans[0].mount,
        mount_source=mount_source,
        warnings=warnings,
    )


def _mounts(got: _Collected, options: ReadOptions) -> tuple[list[LaserMount] | None, str]:
    """The mount of each scan and where it came from: the options, else tf."""
    given = mount_from_options(options.laser_pose, options.laser_flipped)
    if given is not None:
        return [given] * len(got.raw), "given by --laser-pose/--laser-flipped"
    found = mount_from_tf(got.tf, got.laser_frame, got.base_frame, [r.stamp_ns for r in got.raw])
    return found.mounts, found.source


def _usable_range_max(scan: _RawScan) -> float:
    """The message's ``range_max``; when that is unset (0, negative, NaN), just past the largest
    finite reading, so every finite reading is a point."""
    if math.isfinite(scan.range_max) and scan.range_max > 0:
        return scan.range_max
    finite = scan.ranges[np.isfinite(scan.ranges)]
    if finite.size == 0:
        return 0.0
    # Next float32 up: Scan.points compares in float32, as ranges are stored.
    return float(np.nextafter(np.float32(finite.max()), np.float32(np.inf)))


def _odometry_at_scans(
    raw: Sequence[_RawScan],
    odom_ns: Sequence[int],
    odom_poses: Sequence[tuple[float, float, float]],
) -> NDArray[np.float64]:
    """(N, 3) odometry at the scans' times, NaN rows where there is none.

    Times are taken relative to the first message in integer nanoseconds before going to float,
    so epoch-sized stamps (~1.7e9 s) keep sub-microsecond resolution.
    """
    if not odom_ns:
        return np.full((len(raw), 3), np.nan)
    origin = min(odom_ns[0], raw[0].stamp_ns)
    stamps = np.array([t - origin for t in odom_ns], dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    times = np.array([r.stamp_ns - origin for r in raw], dtype=np.int64)
    return interpolate_odometry(
        times.astype(np.float64) / 1e9,
        stamps[order].astype(np.float64) / 1e9,
        np.array(odom_poses, dtype=np.float64)[order],
    )
