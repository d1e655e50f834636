"""Occupancy grid maps: log-odds per cell, one ray per beam, drawn with opencv's Bresenham.

Every beam lowers the log-odds of the cells it crosses and raises the one it ends in. A cell
crossed by several beams of one scan is updated once for that scan. Rays are drawn by
``cv2.polylines`` into a scratch mask the size of the scan's bounding box, so a scan costs
one opencv call and two masked additions, not a Python loop over cells.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.errors import InputError
from vgm_studio.maps.config import MapConfig

_FREE, _HIT = 1, 2


@dataclass
class OccupancyGrid:
    """A log-odds grid; row i spans y ∈ [y0 + i·r, y0 + (i+1)·r), column j spans x likewise.

    Attributes:
        log_odds: (H, W) float32 log-odds, 0 where nothing was seen.
        origin: World (x0, y0) of the corner of cell (0, 0), metres.
        resolution: Cell edge, metres.
    """

    log_odds: NDArray[np.float32]
    origin: tuple[float, float]
    resolution: float

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.log_odds.shape[0]), int(self.log_odds.shape[1]))

    def probabilities(self) -> NDArray[np.float32]:
        """p(occupied) per cell; 0.5 where unknown."""
        return np.asarray(1.0 / (1.0 + np.exp(-self.log_odds)), dtype=np.float32)

    def image(self) -> NDArray[np.uint8]:
        """Grey levels as a person reads a map: free white, occupied black, unknown grey.

        Rows as stored (+y down the array); flip for a picture with +y up.
        """
        return np.asarray(np.round(255.0 * (1.0 - self.probabilities())), dtype=np.uint8)

    def known_cells(self) -> int:
        return int(np.count_nonzero(self.log_odds))


def _world_points(
    poses: NDArray[np.float64], points: Sequence[NDArray[np.float64]]
) -> NDArray[np.float64]:
    moved = [se2.transform_points(p, pts) for p, pts in zip(poses, points, strict=True)]
    return np.vstack([*moved, poses[:, :2]]) if moved else poses[:, :2]


def build_map(
    poses: NDArray[np.float64],
    points: Sequence[NDArray[np.float64]],
    config: MapConfig,
    margin: float = 1.0,
) -> OccupancyGrid:
    """Casts every beam of every scan from its pose into a new grid that holds them all.

    Args:
        poses: (K, 3) sensor poses in the world.
        points: K arrays of (N, 2) beam end points, each in its sensor frame.
        config: Resolution, log-odds increments, clamp and size limit.
        margin: Free border around everything drawn, metres.

    Returns:
        The grid at ``config.resolution``, or coarser where that would exceed
        ``config.max_cells`` on a side (``grid.resolution`` says which).

    Raises:
        InputError: Even cells of ``config.max_resolution`` would exceed ``max_cells``.
    """
    points = [p[np.hypot(p[:, 0], p[:, 1]) <= config.max_range] for p in points]
    world = _world_points(poses, points)
    lo_m = world.min(axis=0) - margin
    extent = world.max(axis=0) + margin - lo_m
    # One cell less: aligning the origin to the cells adds up to one.
    res = max(config.resolution, float(extent.max()) / (config.max_cells - 1))
    if res > config.max_resolution:
        raise InputError(
            None,
            f"the map would be {extent[0]:.0f} m × {extent[1]:.0f} m, over "
            f"{config.max_cells} cells of {config.max_resolution:g} m on a side: "
            "the trajectory is broken",
        )
    lo = np.floor(lo_m / res) * res
    width, height = (int(v) for v in np.ceil((world.max(axis=0) + margin - lo) / res))
    grid = OccupancyGrid(
        np.zeros((height, width), dtype=np.float32), (float(lo[0]), float(lo[1])), res
    )
    for pose, pts in zip(poses, points, strict=True):
        _cast(grid, pose, pts, config)
    return grid


def _cast(
    grid: OccupancyGrid, pose: NDArray[np.float64], pts: NDArray[np.float64], config: MapConfig
) -> None:
    if len(pts) == 0:
        return
    origin = np.asarray(grid.origin)
    ends = np.floor((se2.transform_points(pose, pts) - origin) / grid.resolution).astype(np.int64)
    start = np.floor((pose[:2] - origin) / grid.resolution).astype(np.int64)
    height, width = grid.shape
    cells = np.vstack([ends, start[None]])
    c0, r0 = np.maximum(cells.min(axis=0), 0)
    c1, r1 = np.minimum(cells.max(axis=0) + 1, (width, height))
    if c1 <= c0 or r1 <= r0:
        return
    mask = np.zeros((r1 - r0, c1 - c0), dtype=np.uint8)
    offset = np.array([c0, r0])
    # (x, y) = (column, row) pairs, as opencv draws them.
    lines = np.stack([np.broadcast_to(start - offset, ends.shape), ends - offset], axis=1)
    cv2.polylines(mask, list(lines.astype(np.int32)), isClosed=False, color=_FREE)
    local = ends - offset
    inside = np.all((local >= 0) & (local < (c1 - c0, r1 - r0)), axis=1)
    mask[local[inside, 1], local[inside, 0]] = _HIT
    view = grid.log_odds[r0:r1, c0:c1]
    view[mask == _FREE] += config.log_odds_miss
    view[mask == _HIT] += config.log_odds_hit
    np.clip(view, -config.clamp, config.clamp, out=view)
