"""ROS bags of a simulated robot whose laser sits off the base, written with rosbags' writers.

The world, route and ray casting are vgm_studio.simulation's; the bag holds what a real robot
records: LaserScan in the laser's frame, Odometry of the base, and (optionally) the mount in
/tf_static.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from vgm_studio.core import se2
from vgm_studio.simulation import SimConfig, plan
from vgm_studio.simulation.raycast import cast

NS = 1_000_000_000
T0_NS = 1_700_000_000 * NS


@dataclass(frozen=True)
class SimBag:
    """A simulated run: what to write and the truth to compare with."""

    truth: NDArray[np.float64]  # (N, 3) true base poses
    odometry: NDArray[np.float64]  # (N, 3) the wheels' base poses
    ranges: NDArray[np.float32]  # (N, beams) in the laser's frame
    angle_min: float
    angle_increment: float
    max_range: float
    scan_period: float


def simulate_run(
    mount: tuple[float, float, float, bool] = (0.3, 0.0, 0.0, True),
    scans: int = 160,
    still: bool = False,
    preset: str = "office",
    noisy_odometry: bool = False,
) -> SimBag:
    """The first ``scans`` poses of a preset's route (two corner turns in ``office``), ranges
    cast from a laser at ``mount`` = (x, y, yaw, upside down) on the base. ``still`` keeps the
    robot at its first pose. Odometry is exact, or with ``noisy_odometry`` the simulator's
    default wheel noise and drift (``SimBag.odometry``)."""
    exact = (
        {}
        if noisy_odometry
        else {
            "odom_trans_noise": 0.0,
            "odom_rot_noise_deg": 0.0,
            "odom_turn_noise": 0.0,
            "odom_drift_deg": 0.0,
        }
    )
    config = SimConfig(
        preset=preset, scan_spacing=0.2, num_beams=361, fov_deg=270.0, max_range=20.0, **exact
    )  # type: ignore[arg-type]
    p = plan(config)
    truth = p.truth.poses[:scans].copy()
    odometry = p.odometry[:scans].copy()
    if still:
        truth[:] = truth[0]
        odometry[:] = odometry[0]
    x, y, yaw, flipped = mount
    laser = se2.compose(truth, np.array([x, y, yaw]))
    beams = p.beam_angles()
    rng = np.random.default_rng(7)
    rows = []
    for pose in laser:
        directions = pose[2] + (-beams if flipped else beams)
        r = cast(pose, directions, p.world.walls, config.max_range)
        hit = r < config.max_range
        r = np.where(hit, r + config.range_noise * rng.standard_normal(len(r)), np.inf)
        rows.append(r.astype(np.float32))
    angle_min = float(beams[0])
    return SimBag(
        truth=truth,
        odometry=odometry,
        ranges=np.array(rows),
        angle_min=angle_min,
        angle_increment=float(beams[1] - beams[0]),
        max_range=config.max_range,
        scan_period=config.scan_period,
    )


def _header(ts: Typestore, stamp_ns: int, frame_id: str) -> Any:
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=stamp_ns // NS, nanosec=stamp_ns % NS)
    header: Any = ts.types["std_msgs/msg/Header"]
    if "seq" in header.__dataclass_fields__:  # ROS 1
        return header(seq=0, stamp=stamp, frame_id=frame_id)
    return header(stamp=stamp, frame_id=frame_id)


def _quaternion(ts: Typestore, roll: float, yaw: float) -> Any:
    """q = q_z(yaw) · q_x(roll)."""
    cr, sr, cy, sy = math.cos(roll / 2), math.sin(roll / 2), math.cos(yaw / 2), math.sin(yaw / 2)
    return ts.types["geometry_msgs/msg/Quaternion"](x=cy * sr, y=sy * sr, z=sy * cr, w=cy * cr)


def _odometry(ts: Typestore, stamp_ns: int, pose: NDArray[np.float64]) -> Any:
    t = ts.types
    pose_msg = t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
        orientation=_quaternion(ts, 0.0, float(pose[2])),
    )
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t["nav_msgs/msg/Odometry"](
        header=_header(ts, stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose_msg, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
            covariance=np.zeros(36),
        ),
    )


def _scan(ts: Typestore, stamp_ns: int, run: SimBag, k: int) -> Any:
    ranges = run.ranges[k]
    return ts.types["sensor_msgs/msg/LaserScan"](
        header=_header(ts, stamp_ns, "laser"),
        angle_min=run.angle_min,
        angle_max=run.angle_min + run.angle_increment * (len(ranges) - 1),
        angle_increment=run.angle_increment,
        time_increment=0.0,
        scan_time=run.scan_period,
        range_min=0.02,
        range_max=run.max_range,
        ranges=ranges,
        intensities=np.zeros(0, dtype=np.float32),
    )


def _tf(ts: Typestore, mount: tuple[float, float, float, bool], stamp_ns: int = T0_NS) -> Any:
    t = ts.types
    x, y, yaw, flipped = mount
    transform = t["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, stamp_ns, "base_link"),
        child_frame_id="laser",
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.2),
            rotation=_quaternion(ts, math.pi if flipped else 0.0, yaw),
        ),
    )
    return t["tf2_msgs/msg/TFMessage"](transforms=[transform])


TF_MESSAGE = "geometry_msgs/TransformStamped[] transforms"

TRANSIENT_LOCAL = Qos(
    QosHistory.KEEP_LAST,
    1,
    QosReliability.RELIABLE,
    QosDurability.TRANSIENT_LOCAL,
    QosTime(0, 0),
    QosTime(0, 0),
    QosLiveliness.AUTOMATIC,
    QosTime(0, 0),
    False,
)


def messages(
    ts: Typestore,
    run: SimBag,
    mount: tuple[float, float, float, bool] | None,
    odometry: bool,
    static: bool = True,
) -> list[tuple[str, int, Any]]:
    """(topic, receive time, message): /tf_static first (or /tf with every scan), then scans
    and odometry."""
    out: list[tuple[str, int, Any]] = []
    if mount is not None and static:
        out.append(("/tf_static", T0_NS, _tf(ts, mount)))
    for k in range(len(run.truth)):
        stamp = T0_NS + NS // 10 + round(k * run.scan_period * NS)
        out.append(("/scan", stamp + 1000, _scan(ts, stamp, run, k)))
        if mount is not None and not static:
            out.append(("/tf", stamp + 500, _tf(ts, mount, stamp - 3_000_000)))
        if odometry:
            out.append(("/odom", stamp + 2000, _odometry(ts, stamp, run.odometry[k])))
    return out


def write_sim_bag(
    path: Path,
    run: SimBag,
    *,
    tf_mount: tuple[float, float, float, bool] | None,
    ros2: bool = False,
    odometry: bool = True,
    static: bool = True,
) -> Path:
    """Writes ``run`` as a ROS 1 ``.bag`` (``path``) or a ROS 2 sqlite3 folder; returns it.

    ``tf_mount`` puts the laser's mount in /tf_static (transient-local in ROS 2, as
    ``static_transform_publisher`` offers it), or with ``static=False`` in /tf at every scan.
    """
    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    if not ros2:
        # rosbags' Noetic store lacks tf2_msgs; a ROS 1 bag carries each type's definition.
        ts.register(get_types_from_msg(TF_MESSAGE, "tf2_msgs/msg/TFMessage"))
    msgs = sorted(messages(ts, run, tf_mount, odometry, static), key=lambda m: m[1])
    if not ros2:
        with Writer1(path) as w1:
            conns: dict[str, Any] = {}
            for topic, ns, msg in msgs:
                if topic not in conns:
                    conns[topic] = w1.add_connection(topic, msg.__msgtype__, typestore=ts)
                w1.write(conns[topic], ns, ts.serialize_ros1(msg, msg.__msgtype__))
        return path
    with Writer2(path, version=9) as w2:
        conns = {}
        for topic, ns, msg in msgs:
            if topic not in conns:
                qos = [TRANSIENT_LOCAL] if topic == "/tf_static" else []
                conns[topic] = w2.add_connection(
                    topic, msg.__msgtype__, typestore=ts, offered_qos_profiles=qos
                )
            w2.write(conns[topic], ns, ts.serialize_cdr(msg, msg.__msgtype__))
    return path
