"""Keyframes: the poses a SLAM run and the labeling candidates are built on, picked by how far
the sensor moved or turned since the last one."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2


def select_keyframes(
    poses: NDArray[np.float64], distance: float, angle_deg: float
) -> NDArray[np.int64]:
    """Indices of keyframes: the first pose, then each pose that moved past either threshold."""
    pick = KeyframePicker(distance, angle_deg)
    return np.asarray([i for i, pose in enumerate(poses) if pick(pose)], dtype=np.int64)


class KeyframePicker:
    """``select_keyframes`` a pose at a time, for poses that arrive one by one: called with
    each next pose, it says whether that pose is a keyframe. A threshold not above 0 never
    fires; with both so, every pose is a keyframe."""

    def __init__(self, distance: float, angle_deg: float) -> None:
        self._every = distance <= 0 and angle_deg <= 0
        self._distance = distance if distance > 0 else math.inf
        self._angle = math.radians(angle_deg) if angle_deg > 0 else math.inf
        self._last: NDArray[np.float64] | None = None

    def __call__(self, pose: NDArray[np.float64]) -> bool:
        if not self._every and self._last is not None:
            d = se2.between(self._last, pose)
            if math.hypot(d[0], d[1]) < self._distance and abs(d[2]) < self._angle:
                return False
        self._last = pose
        return True
