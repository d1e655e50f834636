"""SE(2) poses as ``(x, y, θ)`` arrays: composition, inverse and relative poses.

Every function takes single poses of shape (3,) or stacks of shape (N, 3) and broadcasts.
θ is in radians and results are wrapped to (−π, π].
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Pose = NDArray[np.float64]


def wrap_angle(theta: ArrayLike) -> NDArray[np.float64]:
    """Wraps angles to (−π, π]."""
    t = np.asarray(theta, dtype=np.float64)
    return np.pi - np.mod(np.pi - t, 2.0 * np.pi)


def wrap(theta: float) -> float:
    """``wrap_angle`` of one float, without numpy's per-call cost (Python's % is numpy's
    mod)."""
    return math.pi - (math.pi - theta) % (2.0 * math.pi)


def compose(a: ArrayLike, b: ArrayLike) -> Pose:
    """Returns a ∘ b: the pose b, given in the frame of a, expressed in a's parent frame."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape == b.shape == (3,) and math.isfinite(a[2]):
        # One pose each, as the graph search and the cycle checks compose hundreds of
        # thousands of them: floats are 10x faster than numpy's small-array calls.
        ax, ay, at = a.tolist()
        bx, by, bt = b.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([ax + c * bx - s * by, ay + s * bx + c * by, wrap(at + bt)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: ArrayLike) -> Pose:
    """Returns a⁻¹."""
    a = np.asarray(a, dtype=np.float64)
    if a.shape == (3,) and math.isfinite(a[2]):
        x, y, t = a.tolist()
        c, s = math.cos(t), math.sin(t)
        return np.array([-c * x - s * y, s * x - c * y, wrap(-t)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def between(a: ArrayLike, b: ArrayLike) -> Pose:
    """Returns a⁻¹ ∘ b: the pose of b in the frame of a."""
    return compose(inverse(a), b)


def transform_points(pose: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Moves (N, 2) points by ``pose``: p' = R(θ)·p + t."""
    x, y, t = np.asarray(pose, dtype=np.float64).tolist()
    pts = np.asarray(points, dtype=np.float64)
    # Local maps and views move tens of thousands of small clouds: floats, not 0-d arrays.
    c, s = math.cos(t), math.sin(t)
    moved: NDArray[np.float64] = pts @ np.array([[c, s], [-s, c]]) + np.array([x, y])
    return moved


def to_matrix(pose: ArrayLike) -> NDArray[np.float64]:
    """Returns the 3×3 homogeneous matrix of one pose."""
    x, y, t = np.asarray(pose, dtype=np.float64)
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def from_matrix(m: ArrayLike) -> Pose:
    """Returns (x, y, θ) of a 3×3 homogeneous matrix or the planar part of a 4×4 one."""
    m = np.asarray(m, dtype=np.float64)
    return np.array([m[0, -1], m[1, -1], np.arctan2(m[1, 0], m[0, 0])])


def pose_error(reference: ArrayLike, estimate: ArrayLike) -> tuple[float, float]:
    """Returns (|e_xy| in metres, |e_θ| in radians) of e = reference⁻¹ ∘ estimate."""
    e = between(reference, estimate)
    return float(np.hypot(e[0], e[1])), float(abs(e[2]))


def covariance_in_own_frame(covariance: ArrayLike, theta: float) -> NDArray[np.float64]:
    """A pose's (x, y, θ) covariance given in its parent's frame, turned into the pose's own
    frame, where gtsam's Pose2 factors measure their error (translation along the pose's own
    axes, to first order).

    A matcher varies (x, y) along the frame it searches in, the target's. Along a corridor
    its variance is long on one axis; a loop turned by 90° against its target would hold that
    length across the corridor if read in the wrong frame.
    """
    c, s = math.cos(theta), math.sin(theta)
    turn = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    out: NDArray[np.float64] = turn @ np.asarray(covariance, dtype=np.float64) @ turn.T
    return out
