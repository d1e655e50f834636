"""ROS bag reader, on ROS 1 and ROS 2 bags the tests write with rosbags' own writers."""

from __future__ import annotations

import hashlib
import io
import math
import re
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from vgm_studio.core.hashing import content_hash
from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.datasets.rosbag import read_rosbag
from vgm_studio.datasets.scans import MIN_VALID_RANGE
from vgm_studio.errors import InputError

NS = 1_000_000_000
T0_NS = 1_700_000_000 * NS  # an epoch-sized start time, as real bags have
SCAN_OFFSET_NS = 50_000_000 + 1_234  # scans at 0.05 s + 1.234 µs, then every 0.1 s
SCAN_PERIOD_NS = 100_000_000
ODOM_PERIOD_NS = 20_000_000  # odometry at 50 Hz, scans at 10 Hz
RECEIVE_DELAY_NS = 5_000_000  # the bag records each message 5 ms after its header stamp
NUM_SCANS = 20
NUM_BEAMS = 36
RANGE_MAX = 8.0
ANGLE_MIN = -math.pi / 2
ANGLE_INCREMENT = math.pi / (NUM_BEAMS - 1)

# Kinds of bag every round-trip test runs on.
KINDS = ["rosbag1", "rosbag2-sqlite3", "rosbag2-mcap"]

Message = tuple[str, int, Any]  # topic, receive time (ns), message


def true_pose(t: float, offset: float = 0.0) -> np.ndarray:
    """The robot's pose t seconds after T0: straight along x (drifting in y), turning slowly.

    Linear in time, so linear interpolation between odometry samples is exact. Yaw crosses π at
    t = 0.745 s, between the odometry samples at 0.74 s and 0.76 s around the scan at 0.75 s,
    so interpolation must unwrap it.
    """
    yaw = math.pi - 0.149 + 0.2 * t
    return np.array(
        [1.0 + 0.5 * t + offset, -2.0 + 0.1 * t, math.atan2(math.sin(yaw), math.cos(yaw))]
    )


def scan_stamp_ns(k: int) -> int:
    return T0_NS + SCAN_OFFSET_NS + k * SCAN_PERIOD_NS


def scan_ranges(k: int) -> np.ndarray:
    """Known ranges with every kind of reading that is not a point."""
    r = np.linspace(0.5, 5.0, NUM_BEAMS, dtype=np.float32) + np.float32(0.01 * k)
    r[3] = np.inf
    r[5] = -np.inf
    r[7] = np.nan
    r[11] = RANGE_MAX  # "no return" at range_max
    r[12] = RANGE_MAX + 1.5  # beyond range_max
    r[13] = 0.005  # a dropout below MIN_VALID_RANGE
    return r


def valid_mask(r: np.ndarray, max_range: float) -> np.ndarray:
    return np.isfinite(r) & (r >= MIN_VALID_RANGE) & (r < max_range)


def header(ts: Typestore, stamp_ns: int, frame_id: str) -> Any:
    types = ts.types
    stamp = types["builtin_interfaces/msg/Time"](sec=stamp_ns // NS, nanosec=stamp_ns % NS)
    header_type: Any = types["std_msgs/msg/Header"]
    if "seq" in header_type.__dataclass_fields__:  # ROS 1
        return header_type(seq=0, stamp=stamp, frame_id=frame_id)
    return header_type(stamp=stamp, frame_id=frame_id)


def laser_scan(ts: Typestore, stamp_ns: int, ranges: np.ndarray, range_max: float = RANGE_MAX):
    return ts.types["sensor_msgs/msg/LaserScan"](
        header=header(ts, stamp_ns, "laser"),
        angle_min=ANGLE_MIN,
        angle_max=ANGLE_MIN + ANGLE_INCREMENT * (len(ranges) - 1),
        angle_increment=ANGLE_INCREMENT,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.02,
        range_max=range_max,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def odometry(ts: Typestore, stamp_ns: int, pose: np.ndarray) -> Any:
    t = ts.types
    x, y, yaw = (float(v) for v in pose)
    pose_msg = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
        orientation=t["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
        ),
    )
    twist = t["geometry_msgs/msg/Twist"](
        linear=t["geometry_msgs/msg/Vector3"](x=0.5, y=0.1, z=0.0),
        angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.2),
    )
    return t["nav_msgs/msg/Odometry"](
        header=header(ts, stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose_msg, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def scan_messages(ts: Typestore, topic: str = "/scan", zero_stamps: bool = False) -> list[Message]:
    out = []
    for k in range(NUM_SCANS):
        stamp = scan_stamp_ns(k)
        msg = laser_scan(ts, 0 if zero_stamps else stamp, scan_ranges(k))
        out.append((topic, stamp + RECEIVE_DELAY_NS, msg))
    return out


def odom_messages(
    ts: Typestore,
    topic: str = "/odom",
    start_s: float = 0.0,
    stop_s: float = 2.0,
    offset: float = 0.0,
) -> list[Message]:
    out = []
    for j in range(round(start_s * NS / ODOM_PERIOD_NS), round(stop_s * NS / ODOM_PERIOD_NS) + 1):
        stamp = T0_NS + j * ODOM_PERIOD_NS
        msg = odometry(ts, stamp, true_pose((stamp - T0_NS) / NS, offset))
        out.append((topic, stamp + RECEIVE_DELAY_NS, msg))
    return out


def chatter(ts: Typestore) -> list[Message]:
    string = ts.types["std_msgs/msg/String"]
    return [("/chatter", T0_NS + k * NS, string(data=f"hello {k}")) for k in range(3)]


Build = Callable[[Typestore], Sequence[Message]]


def write_bag(tmp_path: Path, kind: str, build: Build, name: str = "run") -> Path:
    """Writes the messages ``build`` makes into a bag of ``kind``; returns its path."""
    if kind == "rosbag1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        path = tmp_path / f"{name}.bag"
        with Writer1(path) as writer:
            connections: dict[str, Any] = {}
            for topic, receive_ns, msg in sorted(build(ts), key=lambda m: m[1]):
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
                writer.write(
                    connections[topic], receive_ns, ts.serialize_ros1(msg, msg.__msgtype__)
                )
        return path
    ts = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if kind.endswith("mcap") else StoragePlugin.SQLITE3
    path = tmp_path / name
    with Writer2(path, version=9, storage_plugin=plugin) as writer2:
        connections = {}
        for topic, receive_ns, msg in sorted(build(ts), key=lambda m: m[1]):
            if topic not in connections:
                connections[topic] = writer2.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer2.write(connections[topic], receive_ns, ts.serialize_cdr(msg, msg.__msgtype__))
    return path


def standard(ts: Typestore) -> list[Message]:
    return scan_messages(ts) + odom_messages(ts) + chatter(ts)


def assert_pose_close(actual: np.ndarray | None, expected: np.ndarray, atol: float = 1e-9) -> None:
    assert actual is not None
    np.testing.assert_allclose(actual[:2], expected[:2], rtol=0, atol=atol)
    dyaw = math.remainder(float(actual[2]) - float(expected[2]), 2 * math.pi)
    assert abs(dyaw) < atol
    assert -math.pi < actual[2] <= math.pi


@pytest.mark.parametrize("kind", KINDS)
def test_round_trip_with_interpolated_odometry(tmp_path: Path, kind: str) -> None:
    path = write_bag(tmp_path, kind, standard)
    log = read_rosbag(path)

    assert log.format == ("rosbag1" if kind == "rosbag1" else "rosbag2")
    assert log.path == path
    assert len(log) == NUM_SCANS
    assert [s.index for s in log.scans] == list(range(NUM_SCANS))
    np.testing.assert_allclose(
        log.timestamps, [scan_stamp_ns(k) / NS for k in range(NUM_SCANS)], rtol=0, atol=1e-6
    )
    assert log.message_counts == {"/scan": NUM_SCANS, "/odom": 101}
    assert log.ignored_messages == {"/chatter": 3}
    assert log.pose_source == "odometry"
    assert log.has_odometry and not log.has_reference
    for k, scan in enumerate(log.scans):
        assert scan.ranges.dtype == np.float32
        np.testing.assert_array_equal(scan.ranges, scan_ranges(k))  # NaN == NaN here
        assert scan.angle_min == pytest.approx(float(np.float32(ANGLE_MIN)), abs=0)
        assert scan.angle_increment == pytest.approx(float(np.float32(ANGLE_INCREMENT)), abs=0)
        assert scan.max_range == RANGE_MAX
        assert scan.reference is None and scan.line == 0
        assert_pose_close(scan.odometry, true_pose((scan_stamp_ns(k) - T0_NS) / NS))
    # The yaw crosses ±π during the run: interpolation must have gone the short way round.
    yaws = np.array([s.odometry[2] for s in log.scans if s.odometry is not None])
    assert yaws.max() > 3.1 and yaws.min() < -3.1


def test_points_drop_non_finite_out_of_range_and_dropout_readings(tmp_path: Path) -> None:
    log = read_rosbag(write_bag(tmp_path, "rosbag1", standard))
    for k, scan in enumerate(log.scans):
        r = scan_ranges(k)
        keep = valid_mask(r, RANGE_MAX)
        assert keep.sum() == NUM_BEAMS - 6
        points = scan.points()
        assert points.shape == (keep.sum(), 2)
        assert np.all(np.isfinite(points))
        angles = np.float32(ANGLE_MIN) + np.float32(ANGLE_INCREMENT) * np.arange(NUM_BEAMS)
        expected = np.stack([r[keep] * np.cos(angles[keep]), r[keep] * np.sin(angles[keep])], 1)
        np.testing.assert_allclose(points, expected, rtol=0, atol=1e-5)


def test_max_range_option_overrides_range_max(tmp_path: Path) -> None:
    log = read_rosbag(write_bag(tmp_path, "rosbag1", standard), ReadOptions(max_range=3.0))
    assert {s.max_range for s in log.scans} == {3.0}
    for k, scan in enumerate(log.scans):
        assert len(scan.points()) == valid_mask(scan_ranges(k), 3.0).sum()
        assert np.hypot(*scan.points().T).max() < 3.0


def test_unset_range_max_keeps_every_finite_reading(tmp_path: Path) -> None:
    ranges = np.array([1.0, 2.0, np.inf, 4.0], dtype=np.float32)
    path = write_bag(
        tmp_path, "rosbag1", lambda ts: [("/scan", T0_NS, laser_scan(ts, T0_NS, ranges, 0.0))]
    )
    scan = read_rosbag(path).scans[0]
    assert 4.0 < scan.max_range < 4.001
    assert len(scan.points()) == 3


def test_content_hash(tmp_path: Path) -> None:
    bag = write_bag(tmp_path, "rosbag1", standard)
    assert read_rosbag(bag).content_hash == hashlib.sha256(bag.read_bytes()).hexdigest()

    folder = write_bag(tmp_path, "rosbag2-sqlite3", standard)
    first = read_rosbag(folder).content_hash
    assert len(first) == 64
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    assert read_rosbag(copy).content_hash == first  # by content and names within the folder
    with (copy / "metadata.yaml").open("a") as f:
        f.write("\n")
    assert read_rosbag(copy).content_hash != first


def test_folder_hash_covers_names_and_contents(tmp_path: Path) -> None:
    def folder(name: str, files: dict[str, bytes]) -> Path:
        path = tmp_path / name
        path.mkdir()
        for file, data in files.items():
            (path / file).write_bytes(data)
        return path

    base = content_hash(folder("a", {"a.db3": b"xy", "metadata.yaml": b"z"}))
    assert content_hash(folder("b", {"a.db3": b"xy", "metadata.yaml": b"z"})) == base
    assert content_hash(folder("c", {"b.db3": b"xy", "metadata.yaml": b"z"})) != base  # renamed
    assert content_hash(folder("d", {"a.db3": b"x", "metadata.yaml": b"yz"})) != base  # moved byte
    # Names and bytes run together alike unless sizes separate them.
    assert content_hash(folder("e", {"a": b"b\0c"})) != content_hash(
        folder("f", {"a": b"", "b": b"c"})
    )


def test_open_log_dispatches_bags(tmp_path: Path) -> None:
    bag = write_bag(tmp_path, "rosbag1", standard)
    folder = write_bag(tmp_path, "rosbag2-sqlite3", standard, name="ros2")
    assert open_log(bag).format == "rosbag1"
    ros2 = open_log(folder)
    assert ros2.format == "rosbag2" and len(ros2) == NUM_SCANS
    (db3,) = folder.glob("*.db3")
    storage_only = open_log(db3)  # a bare ROS 2 storage file reads too
    assert storage_only.format == "rosbag2"
    np.testing.assert_array_equal(storage_only.timestamps, ros2.timestamps)


def test_no_odometry_topic(tmp_path: Path) -> None:
    log = read_rosbag(write_bag(tmp_path, "rosbag2-mcap", scan_messages))
    assert len(log) == NUM_SCANS
    assert all(s.odometry is None for s in log.scans)
    assert log.pose_source is None and not log.has_odometry
    assert log.message_counts == {"/scan": NUM_SCANS}


def test_scans_outside_the_odometry_span(tmp_path: Path) -> None:
    """Odometry from 0.5 s to 1.0 s: nearest pose up to 0.5 s outside, none beyond."""
    path = write_bag(
        tmp_path,
        "rosbag1",
        lambda ts: scan_messages(ts) + odom_messages(ts, start_s=0.5, stop_s=1.0),
    )
    log = read_rosbag(path)
    assert log.pose_source == "odometry" and not log.has_odometry
    for k, scan in enumerate(log.scans):
        t = (scan_stamp_ns(k) - T0_NS) / NS
        if t > 1.5:
            assert scan.odometry is None, t
        else:
            assert_pose_close(scan.odometry, true_pose(min(max(t, 0.5), 1.0)))
    assert sum(s.odometry is None for s in log.scans) == 5  # 1.55 … 1.95 s


def test_odometry_with_a_non_finite_pose_is_skipped(tmp_path: Path) -> None:
    def build(ts: Typestore) -> list[Message]:
        bad_ns = scan_stamp_ns(10) - 1_000  # just before a scan: it would interpolate to NaN
        bad = ("/odom", bad_ns, odometry(ts, bad_ns, np.array([np.nan, 0.0, 0.0])))
        return [*scan_messages(ts), *odom_messages(ts), bad]

    log = read_rosbag(write_bag(tmp_path, "rosbag2-mcap", build))
    assert log.message_counts["/odom"] == 102
    for k, scan in enumerate(log.scans):
        assert_pose_close(scan.odometry, true_pose((scan_stamp_ns(k) - T0_NS) / NS))


def test_zero_header_stamp_falls_back_to_receive_time(tmp_path: Path) -> None:
    path = write_bag(
        tmp_path,
        "rosbag2-sqlite3",
        lambda ts: scan_messages(ts, zero_stamps=True) + odom_messages(ts),
    )
    log = read_rosbag(path)
    received = [(scan_stamp_ns(k) + RECEIVE_DELAY_NS) / NS for k in range(NUM_SCANS)]
    np.testing.assert_allclose(log.timestamps, received, rtol=0, atol=1e-6)
    for k, scan in enumerate(log.scans):  # odometry (with real stamps) taken at the receive time
        assert_pose_close(
            scan.odometry, true_pose((scan_stamp_ns(k) + RECEIVE_DELAY_NS - T0_NS) / NS)
        )


def two_scan_topics(ts: Typestore) -> list[Message]:
    rear = [
        ("/scan_rear", receive, laser_scan(ts, scan_stamp_ns(k), np.full(NUM_BEAMS, 2.5)))
        for k, (_, receive, _) in enumerate(scan_messages(ts))
    ]
    return scan_messages(ts, "/scan_front") + rear[:7] + odom_messages(ts)


@pytest.mark.parametrize("kind", ["rosbag1", "rosbag2-mcap"])
def test_two_scan_topics_need_a_choice(tmp_path: Path, kind: str) -> None:
    path = write_bag(tmp_path, kind, two_scan_topics)
    with pytest.raises(InputError) as err:
        read_rosbag(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ")
    assert "/scan_front" in message and "/scan_rear" in message and "--scan-topic" in message

    rear = read_rosbag(path, ReadOptions(scan_topic="/scan_rear"))
    assert len(rear) == 7
    assert all(np.all(s.ranges == np.float32(2.5)) for s in rear.scans)
    assert rear.message_counts == {"/scan_rear": 7, "/odom": 101}
    assert rear.ignored_messages == {"/scan_front": NUM_SCANS}
    assert len(read_rosbag(path, ReadOptions(scan_topic="/scan_front"))) == NUM_SCANS

    with pytest.raises(InputError, match=r"/nope is not in this bag.*/scan_front"):
        read_rosbag(path, ReadOptions(scan_topic="/nope"))
    with pytest.raises(InputError, match=r"/odom carries nav_msgs/msg/Odometry"):
        read_rosbag(path, ReadOptions(scan_topic="/odom"))


def test_two_odometry_topics_need_a_choice(tmp_path: Path) -> None:
    path = write_bag(
        tmp_path,
        "rosbag1",
        lambda ts: scan_messages(ts) + odom_messages(ts) + odom_messages(ts, "/odom_b", offset=10),
    )
    with pytest.raises(InputError, match=r"/odom, /odom_b.*--odom-topic"):
        read_rosbag(path)
    log = read_rosbag(path, ReadOptions(odom_topic="/odom_b"))
    for k, scan in enumerate(log.scans):
        assert_pose_close(scan.odometry, true_pose((scan_stamp_ns(k) - T0_NS) / NS, offset=10))
    with pytest.raises(InputError, match="--odom-topic /scan carries sensor_msgs/msg/LaserScan"):
        read_rosbag(path, ReadOptions(odom_topic="/scan"))


def write_garbage(tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    path.write_bytes(bytes(range(256)) * 8)
    return path


def empty_bag(tmp_path: Path) -> Path:
    path = tmp_path / "empty.bag"
    path.write_bytes(b"")
    return path


def truncated_bag(tmp_path: Path) -> Path:
    bag = write_bag(tmp_path, "rosbag1", standard, name="whole")
    data = bag.read_bytes()
    path = tmp_path / "truncated.bag"
    path.write_bytes(data[: len(data) // 2])
    return path


def ros2_with_garbage_storage(tmp_path: Path) -> Path:
    folder = write_bag(tmp_path, "rosbag2-sqlite3", standard, name="ros2")
    (db3,) = folder.glob("*.db3")
    db3.write_bytes(b"SQLite format 3\0" + bytes(range(256)) * 16)
    return folder


def ros2_with_truncated_storage(tmp_path: Path) -> Path:
    """Cut inside the last sqlite page: the database opens, reading the messages fails."""
    folder = write_bag(tmp_path, "rosbag2-sqlite3", standard, name="ros2")
    (db3,) = folder.glob("*.db3")
    data = db3.read_bytes()
    db3.write_bytes(data[: len(data) - 1000])
    return folder


def ros2_with_garbage_metadata(tmp_path: Path) -> Path:
    folder = write_bag(tmp_path, "rosbag2-mcap", standard, name="ros2")
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    return folder


def empty_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "not_a_bag"
    folder.mkdir()
    (folder / "notes.txt").write_text("hello\n")
    return folder


def empty_scan_topic(tmp_path: Path) -> Path:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "empty_scan"
    with Writer2(path, version=9) as writer:
        writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        for _, receive_ns, msg in odom_messages(ts):
            writer.write(odom, receive_ns, ts.serialize_cdr(msg, msg.__msgtype__))
    return path


def odometry_only(tmp_path: Path) -> Path:
    return write_bag(tmp_path, "rosbag1", lambda ts: odom_messages(ts) + chatter(ts))


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (lambda p: p / "missing.bag", "no such file or folder"),
        (empty_folder, "no metadata.yaml"),
        (lambda p: write_garbage(p, "garbage.bag"), "not a readable ROS bag"),
        (lambda p: write_garbage(p, "garbage.mcap"), "not a readable ROS bag"),
        (empty_bag, "not a readable ROS bag"),
        (truncated_bag, "not a readable ROS bag"),
        (ros2_with_garbage_storage, "not a readable ROS bag"),
        (ros2_with_truncated_storage, "not a readable ROS bag"),
        (ros2_with_garbage_metadata, "not a readable ROS bag"),
        (lambda p: write_garbage(p, "scan.txt"), "not a ROS bag"),
        (empty_scan_topic, "no messages on the LaserScan topic /scan"),
        (odometry_only, r"no sensor_msgs/LaserScan topic.*/odom \(nav_msgs/msg/Odometry, 101\)"),
    ],
    ids=[
        "missing",
        "folder-not-a-bag",
        "garbage-bag",
        "garbage-mcap",
        "empty-bag",
        "truncated-bag",
        "ros2-garbage-db3",
        "ros2-truncated-db3",
        "ros2-garbage-metadata",
        "not-a-bag-suffix",
        "empty-scan-topic",
        "no-laserscan",
    ],
)
def test_bad_input_is_one_line_error_naming_the_path(
    tmp_path: Path, make: Callable[[Path], Path], expected: str
) -> None:
    path = make(tmp_path)
    with pytest.raises(InputError, match=expected) as err:
        read_rosbag(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ")
    assert "\n" not in message
    assert err.value.path == str(path)


def test_open_log_reports_a_garbage_bag(tmp_path: Path) -> None:
    path = write_garbage(tmp_path, "garbage.bag")
    with pytest.raises(InputError, match="not a readable ROS bag") as err:
        open_log(path)
    assert str(err.value).startswith(f"{path}: ")


@pytest.mark.parametrize("terminal", [True, False])
def test_progress_a_bar_on_a_terminal_and_a_line_elsewhere(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, terminal: bool
) -> None:
    class Stderr(io.StringIO):
        def isatty(self) -> bool:
            return terminal

    path = write_bag(tmp_path, "rosbag1", standard)
    stderr = Stderr()
    monkeypatch.setattr(sys, "stderr", stderr)
    read_rosbag(path)
    total = NUM_SCANS + 101  # /chatter is not read
    if terminal:
        assert f"{total}/{total}" in stderr.getvalue() and path.name in stderr.getvalue()
    else:  # a pipe or a log file: one plain line where the reading ended, no bar
        assert re.fullmatch(
            rf"{re.escape(path.name)}: {total}/{total} messages \(100%\) \d+ s\n",
            stderr.getvalue(),
        )


def scan_among_others(ts: Typestore) -> list[Message]:
    """/scan beside a second and a third LaserScan topic, as robots with several lasers record."""
    others = [
        (topic, receive, laser_scan(ts, scan_stamp_ns(k), np.full(NUM_BEAMS, 2.5)))
        for topic in ("/scan_rear", "/lidar/scan")
        for k, (_, receive, _) in enumerate(scan_messages(ts))
    ]
    return scan_messages(ts) + others + odom_messages(ts)


@pytest.mark.parametrize("kind", ["rosbag1", "rosbag2-mcap"])
def test_of_several_scan_topics_scan_is_read_with_a_warning(tmp_path: Path, kind: str) -> None:
    path = write_bag(tmp_path, kind, scan_among_others)
    log = read_rosbag(path)
    assert log.message_counts == {"/scan": NUM_SCANS, "/odom": 101}
    assert log.ignored_messages == {"/scan_rear": NUM_SCANS, "/lidar/scan": NUM_SCANS}
    assert log.warnings == [
        f"{path}: 3 sensor_msgs/LaserScan topics; reading /scan (not /lidar/scan, "
        "/scan_rear); choose another with --scan-topic"
    ]
    # Asked for, another topic is read without a word.
    rear = read_rosbag(path, ReadOptions(scan_topic="/scan_rear"))
    assert rear.message_counts["/scan_rear"] == NUM_SCANS and rear.warnings == []


def test_the_commands_print_which_scan_topic_they_read(tmp_path: Path) -> None:
    path = write_bag(tmp_path, "rosbag2-mcap", scan_among_others)
    exe = shutil.which("vgm-studio")
    cmd = [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]
    for args in (["info", path], ["candidates", path, "--out", tmp_path / "e.jsonl"]):
        proc = subprocess.run(
            [*cmd, *map(str, args)], capture_output=True, text=True, timeout=600, check=False
        )
        assert proc.returncode == 0, proc.stderr
        warned = [line for line in proc.stderr.splitlines() if "LaserScan topics" in line]
        assert warned == [
            f"{path}: 3 sensor_msgs/LaserScan topics; reading /scan (not /lidar/scan, "
            "/scan_rear); choose another with --scan-topic"
        ], proc.stderr


def _index_pos_at(data: bytes) -> tuple[int, int]:
    """(offset of the header's index_pos value, index_pos) of a ROS 1 (2.0) bag."""
    at = data.index(b"index_pos=") + len(b"index_pos=")
    return at, int.from_bytes(data[at : at + 8], "little")


def old_format_bag(tmp_path: Path) -> Path:
    data = write_bag(tmp_path, "rosbag1", standard, name="whole").read_bytes()
    path = tmp_path / "old.bag"
    path.write_bytes(b"#ROSRECORD V1.2\n" + data[len(b"#ROSBAG V2.0\n") :])
    return path


def unindexed_bag(tmp_path: Path) -> Path:
    """A recording cut short: the header's index_pos was never written (still 0)."""
    data = bytearray(write_bag(tmp_path, "rosbag1", standard, name="whole").read_bytes())
    at, _ = _index_pos_at(bytes(data))
    data[at : at + 8] = bytes(8)
    path = tmp_path / "unindexed.bag"
    path.write_bytes(bytes(data))
    return path


def damaged_index_bag(tmp_path: Path) -> Path:
    """The whole file is there, but its index records are overwritten."""
    data = bytearray(write_bag(tmp_path, "rosbag1", standard, name="whole").read_bytes())
    _, index_pos = _index_pos_at(bytes(data))
    data[index_pos + 4 : index_pos + 60] = b"\xff" * 56
    path = tmp_path / "damaged.bag"
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize(
    ("make", "reason", "remedy"),
    [
        (old_format_bag, "ROSRECORD V1.2 is older than 2.0", "`rosbag fix old.bag NEW.bag`"),
        (truncated_bag, r"the file is truncated \(", "`rosbag reindex truncated.bag`"),
        (unindexed_bag, "the bag has no index", "`rosbag reindex unindexed.bag`"),
        (damaged_index_bag, "rosbags rejects its index", "`rosbags-convert --src damaged.bag"),
        (empty_bag, "an empty file", ""),
    ],
    ids=["format-1.2", "truncated", "unindexed", "damaged-index", "empty"],
)
def test_unreadable_ros1_bag_says_why_and_what_to_do(
    tmp_path: Path, make: Callable[[Path], Path], reason: str, remedy: str
) -> None:
    path = make(tmp_path)
    with pytest.raises(InputError) as err:
        read_rosbag(path)
    message = str(err.value)
    assert message.startswith(f"{path}: not a readable ROS bag: ")
    assert "\n" not in message
    assert re.search(reason, message), message
    assert remedy in message
