"""The laser's mount from a bag's ``/tf_static`` and ``/tf``: the chain from the scan's frame to
the robot's base frame.

Transforms form a tree (each frame has one parent). A static transform holds at every time;
a dynamic one is taken from the message nearest the scan's time. Frame names are compared
without a leading ``/`` (ROS 1 bags often write ``/base_link``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.datasets.mount import LaserMount, mount_from_matrix

TF_TYPES = frozenset({"tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage", "tf/tfMessage"})
# Base frames tried, in order, when a bag has no odometry to name its base.
BASE_FRAMES = ("base_link", "base_footprint")
# A mount that moves less than this between scans (metres, radians) is one fixed mount.
_STEADY = 1e-4


def frame(name: str) -> str:
    return name.lstrip("/")


Transform = tuple[float, float, float, float, float, float, float]  # x y z, qx qy qz qw


def _values(translation: Any, rotation: Any) -> Transform:
    v = translation
    q = rotation
    return (
        float(v.x), float(v.y), float(v.z), float(q.x), float(q.y), float(q.z), float(q.w)
    )  # fmt: skip


def _matrix(t: Transform) -> NDArray[np.float64]:
    """4×4 transform of a translation and a quaternion (normalised first)."""
    q = np.array(t[3:], dtype=np.float64)
    norm = float(np.linalg.norm(q))
    x, y, z, w = q / norm if norm > 0 else (0.0, 0.0, 0.0, 1.0)
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = t[:3]
    return m


@dataclass
class _Link:
    """One frame's transforms to its parent over time.

    A value is kept only when it changes, so a fixed joint that ``robot_state_publisher``
    sends on /tf at 50 Hz costs one entry; a lookup takes the last value at or before the
    time asked (the first before any).
    """

    parent: str
    stamps: list[int] = field(default_factory=list)
    values: list[Transform] = field(default_factory=list)
    _ordered: bool = True

    def add(self, stamp_ns: int, value: Transform) -> None:
        if self.values and self.values[-1] == value:
            return
        self._ordered = self._ordered and (not self.stamps or stamp_ns >= self.stamps[-1])
        self.stamps.append(stamp_ns)
        self.values.append(value)

    def at(self, stamp_ns: int) -> NDArray[np.float64]:
        if not self._ordered:
            order = sorted(range(len(self.stamps)), key=self.stamps.__getitem__)
            self.stamps = [self.stamps[i] for i in order]
            self.values = [self.values[i] for i in order]
            self._ordered = True
        i = int(np.searchsorted(self.stamps, stamp_ns, side="right")) - 1
        return _matrix(self.values[max(i, 0)])


@dataclass
class TfTree:
    """Static and dynamic transforms read from a bag, child → parent."""

    static: dict[str, _Link] = field(default_factory=dict)
    dynamic: dict[str, _Link] = field(default_factory=dict)

    def add_message(self, msg: Any, stamp_ns: int, static: bool) -> None:
        """Adds a TFMessage's transforms (a static one replaces what its child had)."""
        for t in msg.transforms:
            child, parent = frame(t.child_frame_id), frame(t.header.frame_id)
            value = _values(t.transform.translation, t.transform.rotation)
            if not child or not parent or child == parent or not all(map(math.isfinite, value)):
                continue
            if static:
                self.static[child] = _Link(parent, [0], [value])
                continue
            link = self.dynamic.setdefault(child, _Link(parent))
            ns = int(t.header.stamp.sec) * 1_000_000_000 + int(t.header.stamp.nanosec) or stamp_ns
            link.add(ns, value)

    def __bool__(self) -> bool:
        return bool(self.static or self.dynamic)

    def _link(self, child: str) -> _Link | None:
        return self.static.get(child) or self.dynamic.get(child)

    def _ancestors(self, name: str) -> list[str]:
        chain = [name]
        while (link := self._link(chain[-1])) is not None and link.parent not in chain:
            chain.append(link.parent)
        return chain

    def has_frame(self, name: str) -> bool:
        return (
            name in self.static
            or name in self.dynamic
            or any(link.parent == name for link in (*self.static.values(), *self.dynamic.values()))
        )

    def is_static_between(self, source: str, target: str) -> bool:
        path = self._path(source, target)
        return not any(f in self.dynamic and f not in self.static for f in path)

    def _path(self, source: str, target: str) -> list[str]:
        """Frames whose link to their parent lies on the way from source to target."""
        up, down = self._ancestors(source), self._ancestors(target)
        common = next((f for f in up if f in down), None)
        if common is None:
            return []
        return up[: up.index(common)] + down[: down.index(common)]

    def lookup(self, source: str, target: str, stamp_ns: int) -> NDArray[np.float64] | None:
        """4×4 pose of ``source`` in ``target`` at ``stamp_ns``, None when they are not linked."""
        up, down = self._ancestors(source), self._ancestors(target)
        common = next((f for f in up if f in down), None)
        if common is None:
            return None

        def to_common(chain: list[str]) -> NDArray[np.float64]:
            m = np.eye(4)
            for child in chain[: chain.index(common)]:
                link = self._link(child)
                assert link is not None  # every frame before the common one has a parent
                m = link.at(stamp_ns) @ m
            return m

        return np.asarray(np.linalg.inv(to_common(down)) @ to_common(up))


@dataclass(frozen=True)
class TfMount:
    """The mount tf gives, per scan, and a line saying where it came from."""

    mounts: list[LaserMount] | None
    source: str


def mount_from_tf(
    tree: TfTree, laser_frame: str, base_frame: str | None, stamps_ns: Sequence[int]
) -> TfMount:
    """The laser's mount at each scan's time, from the chain laser frame → base frame.

    Args:
        tree: The bag's transforms.
        laser_frame: The LaserScan's ``header.frame_id``.
        base_frame: The Odometry's ``child_frame_id``; None tries ``BASE_FRAMES``.
        stamps_ns: The scans' times.
    """
    laser_frame = frame(laser_frame)
    if not laser_frame:
        return TfMount(None, "the scans name no frame (empty header.frame_id)")
    if base_frame is None:
        base_frame = next((f for f in BASE_FRAMES if tree.has_frame(f)), None)
        if base_frame is None:
            return TfMount(None, f"no odometry names the base and tf has no {BASE_FRAMES[0]}")
    base_frame = frame(base_frame)
    if laser_frame == base_frame:
        return TfMount(None, f"the scans are in {base_frame}")
    if not tree:
        return TfMount(None, "the bag has no /tf or /tf_static")
    if tree.lookup(laser_frame, base_frame, stamps_ns[0]) is None:
        return TfMount(None, f"tf has no chain from {laser_frame!r} to {base_frame!r}")
    topic = "/tf_static" if tree.is_static_between(laser_frame, base_frame) else "/tf"
    if topic == "/tf_static":
        m = tree.lookup(laser_frame, base_frame, 0)
        assert m is not None
        mount = mount_from_matrix(m)
        return TfMount([mount] * len(stamps_ns), f"from {topic}, {laser_frame} in {base_frame}")
    mounts = []
    for ns in stamps_ns:
        m = tree.lookup(laser_frame, base_frame, ns)
        assert m is not None
        mounts.append(mount_from_matrix(m))
    poses = np.array([[m.x, m.y, m.yaw] for m in mounts])
    spread = float(np.max(np.ptp(poses, axis=0))) if len(poses) else 0.0
    note = "" if spread < _STEADY else f", moving by up to {spread:.3g} m or rad"
    return TfMount(mounts, f"from {topic}, {laser_frame} in {base_frame} at each scan's time{note}")
