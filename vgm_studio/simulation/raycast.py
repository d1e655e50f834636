"""Vectorised 2D ray casting of a fan of beams against wall segments and circles."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray


def beam_angles(num_beams: int, fov_deg: float) -> tuple[float, float]:
    """Returns (angle_min, angle_increment) in radians of a scan centred on the heading.

    Beams span −fov/2 … +fov/2 end to end. A full circle instead steps 2π/num_beams so that
    the last beam does not repeat the first.
    """
    if num_beams < 2:
        raise ValueError(f"need at least 2 beams, got {num_beams}")
    fov = math.radians(fov_deg)
    if fov_deg >= 360.0:
        return -math.pi, 2.0 * math.pi / num_beams
    return -fov / 2.0, fov / (num_beams - 1)


def _segment_distances(
    origin: NDArray[np.float64], walls: NDArray[np.float64]
) -> NDArray[np.float64]:
    a, e = walls[:, :2] - origin, walls[:, 2:] - walls[:, :2]
    u = np.clip(-np.sum(a * e, axis=1) / np.maximum(np.sum(e * e, axis=1), 1e-300), 0.0, 1.0)
    distance: NDArray[np.float64] = np.hypot(*(a + u[:, None] * e).T)
    return distance


def cast(
    origin: ArrayLike,
    angles: ArrayLike,
    walls: NDArray[np.float64],
    max_range: float,
    centres: NDArray[np.float64] | None = None,
    radii: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Returns the range of each beam to the nearest wall or circle.

    Args:
        origin: Beam origin (x, y), or a pose (x, y, θ) whose θ is ignored.
        angles: (N,) world-frame beam directions in radians.
        walls: (M, 4) segments ``x1 y1 x2 y2``.
        max_range: Beams that hit nothing closer return exactly this.
        centres: (P, 2) circle centres (people), or None.
        radii: (P,) circle radii.

    Returns:
        (N,) ranges in metres, at most ``max_range``.
    """
    o = np.asarray(origin, dtype=np.float64)[:2]
    a = np.asarray(angles, dtype=np.float64)
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    best = np.full(a.shape[0], np.inf)
    # Segments wholly beyond max_range cannot matter; dropping them keeps big worlds cheap.
    near = walls[_segment_distances(o, walls) < max_range] if len(walls) else walls
    if len(near):
        p, e = near[:, :2] - o, near[:, 2:] - near[:, :2]
        # o + t·d = p + u·e  ⇒  t = (p × e)/(d × e), u = (p × d)/(d × e)
        denom = np.outer(d[:, 0], e[:, 1]) - np.outer(d[:, 1], e[:, 0])
        num_u = np.outer(d[:, 1], p[:, 0]) - np.outer(d[:, 0], p[:, 1])
        num_t = p[:, 0] * e[:, 1] - p[:, 1] * e[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num_t / denom
            u = num_u / denom
        t[~((t > 0.0) & (u >= 0.0) & (u <= 1.0))] = np.inf
        best = t.min(axis=1)
    if centres is not None and radii is not None and len(centres):
        q = np.asarray(centres, dtype=np.float64) - o
        c = np.sum(q * q, axis=1) - np.asarray(radii, dtype=np.float64) ** 2
        b = d @ q.T
        disc = b * b - c
        with np.errstate(invalid="ignore"):
            t = b - np.sqrt(disc)
        # From inside a circle the near root is negative, so a person walking through the
        # sensor does not blind it.
        t[~((disc >= 0.0) & (t > 0.0))] = np.inf
        best = np.minimum(best, t.min(axis=1))
    ranges: NDArray[np.float64] = np.minimum(best, max_range)
    return ranges
