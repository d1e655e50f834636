"""Occupancy grids as ROS map_server / Nav2 load them: a trinary PGM and its YAML.

map_server reads a pixel's grey level v as p(occupied) = (255 - v) / 255 (``negate: 0``) and
calls it occupied above ``occupied_thresh``, free below ``free_thresh``, unknown between. The
three levels written here (0, 254, 205: map_saver's own) land on those three sides of the same
thresholds, so the map loads as the cells it was decided from. The image's first row is the
top of the map (highest y); ``origin`` is the world pose of the lower-left corner of the
lower-left pixel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.atomic import atomic_path, write_text_atomically
from vgm_studio.errors import InputError
from vgm_studio.maps.occupancy import OccupancyGrid

OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
OCCUPIED, FREE, UNKNOWN = 0, 254, 205


def trinary_image(grid: OccupancyGrid) -> NDArray[np.uint8]:
    """The grid's cells as map_server's trinary grey levels, first row the top of the map."""
    p = grid.probabilities()
    image = np.full(p.shape, UNKNOWN, dtype=np.uint8)
    # The same strict comparisons as map_server's loader, so a cell at a threshold reads back
    # as the level it was written with.
    image[p > OCCUPIED_THRESH] = OCCUPIED
    image[p < FREE_THRESH] = FREE
    return np.ascontiguousarray(image[::-1])


def map_yaml(grid: OccupancyGrid, image: str) -> str:
    """The map's YAML for the image file named ``image`` (relative to the YAML's folder)."""
    x, y = grid.origin
    return (
        f"image: {image}\n"
        f"resolution: {float(grid.resolution)!r}\n"
        f"origin: [{float(x)!r}, {float(y)!r}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n"
        "mode: trinary\n"
    )


def write_ros_map(folder: Path, grid: OccupancyGrid, name: str = "map") -> list[Path]:
    """Writes ``folder/<name>.pgm`` (binary P5, 8-bit) and ``folder/<name>.yaml``.

    Each file is written whole or not at all, the image first, so the YAML never names an
    image that is not there.

    Args:
        folder: Where to write; made if missing.
        grid: The map.
        name: The files' stem.

    Returns:
        The image's path and the YAML's, in that order.

    Raises:
        ValueError: ``name`` is not a plain file stem.
        InputError: A file cannot be written.
    """
    if not name or Path(name).name != name or name in {".", ".."}:
        raise ValueError(f"{name!r} is not a file name")
    pgm, yaml = folder / f"{name}.pgm", folder / f"{name}.yaml"
    image = trinary_image(grid)
    height, width = image.shape
    header = f"P5\n# vgm-studio occupancy grid\n{width} {height}\n255\n"
    try:
        with atomic_path(pgm) as tmp:
            tmp.write_bytes(header.encode("ascii") + image.tobytes())
    except OSError as exc:
        raise InputError(pgm, f"cannot write ({exc.strerror or exc})") from None
    try:
        write_text_atomically(yaml, map_yaml(grid, pgm.name))
    except OSError as exc:
        raise InputError(yaml, f"cannot write ({exc.strerror or exc})") from None
    return [pgm, yaml]
