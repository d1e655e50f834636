"""Two after maps drawn over each other: walls both runs agree on in black, walls only one
run has in that run's colour."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.maps.occupancy import OccupancyGrid

# BGR, as opencv writes them; blue and orange stay apart for red-green colour blindness.
BASE_COLOUR = (255, 110, 0)
NEW_COLOUR = (0, 120, 255)
_FREE = (255, 255, 255)
_UNKNOWN = (205, 205, 205)
# p(occupied) over which a cell is a wall, and under which it is free.
_WALL, _OPEN = 0.65, 0.35


def _on_canvas(
    grid: OccupancyGrid, lo: NDArray[np.float64], shape: tuple[int, int]
) -> NDArray[np.float32]:
    """The grid's probabilities placed on a canvas whose cell (0, 0) has its corner at ``lo``."""
    canvas = np.full(shape, 0.5, dtype=np.float32)
    r0, c0 = (round(float(v)) for v in (np.asarray(grid.origin)[::-1] - lo[::-1]) / grid.resolution)
    h, w = grid.shape
    canvas[r0 : r0 + h, c0 : c0 + w] = grid.probabilities()
    return canvas


def overlay(base: OccupancyGrid, new: OccupancyGrid) -> NDArray[np.uint8]:
    """The two maps over each other as a BGR picture, +y up, with a legend.

    Both grids must share a resolution (``build_map`` aligns each origin to whole cells of
    it, so they then share a lattice too).
    """
    if not np.isclose(base.resolution, new.resolution):
        raise ValueError("the two maps have different cell sizes")
    res = base.resolution
    lo = np.minimum(base.origin, new.origin)
    hi = np.maximum(
        np.asarray(base.origin) + np.array(base.shape[::-1]) * res,
        np.asarray(new.origin) + np.array(new.shape[::-1]) * res,
    )
    width, height = (round(float(v)) for v in (hi - lo) / res)
    pb = _on_canvas(base, lo, (height, width))
    pn = _on_canvas(new, lo, (height, width))
    wall_b, wall_n = pb > _WALL, pn > _WALL
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[:] = _UNKNOWN
    image[(pb < _OPEN) | (pn < _OPEN)] = _FREE
    image[wall_b & ~wall_n] = BASE_COLOUR
    image[wall_n & ~wall_b] = NEW_COLOUR
    image[wall_b & wall_n] = (0, 0, 0)
    image = np.ascontiguousarray(image[::-1])
    _legend(image)
    return image


def _legend(image: NDArray[np.uint8]) -> None:
    entries = (("base only", BASE_COLOUR), ("new only", NEW_COLOUR), ("both", (0, 0, 0)))
    for i, (text, colour) in enumerate(entries):
        y = 20 + 22 * i
        cv2.line(image, (8, y - 5), (36, y - 5), colour, 3)
        cv2.putText(image, text, (44, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 0, 1, cv2.LINE_AA)


# The corner the legend covers (rows, columns).
LEGEND = (70, 130)


def coloured_cells(image: NDArray[np.uint8]) -> dict[str, int]:
    """How many pixels carry each run's own colour, the legend's corner left out."""
    body = image.copy()
    body[: LEGEND[0], : LEGEND[1]] = _FREE
    return {
        "base": int(np.all(body == BASE_COLOUR, axis=2).sum()),
        "new": int(np.all(body == NEW_COLOUR, axis=2).sum()),
    }
