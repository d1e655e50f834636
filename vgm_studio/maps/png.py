"""Map pictures: one grid as a PNG, or several side by side with a title over each."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.errors import InputError
from vgm_studio.maps.occupancy import OccupancyGrid

_TITLE_H = 36
_GAP = 12
_PAPER = 255


def picture(grid: OccupancyGrid) -> NDArray[np.uint8]:
    """The grid as a grey image with +y up, as maps are read."""
    return np.ascontiguousarray(grid.image()[::-1])


def side_by_side(grids: Sequence[OccupancyGrid], titles: Sequence[str]) -> NDArray[np.uint8]:
    """The grids' pictures in one row, each under its title, padded to one height."""
    images = [picture(g) for g in grids]
    height = max(i.shape[0] for i in images)
    panels = []
    for img, title in zip(images, titles, strict=True):
        pad = np.full((height - img.shape[0], img.shape[1]), _PAPER, dtype=np.uint8)
        panel = np.vstack([np.full((_TITLE_H, img.shape[1]), _PAPER, np.uint8), img, pad])
        cv2.putText(panel, title, (6, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.8, 0, 2, cv2.LINE_AA)
        panels.append(panel)
        panels.append(np.full((panel.shape[0], _GAP), _PAPER, dtype=np.uint8))
    return np.hstack(panels[:-1])


def write_png(path: Path, image: NDArray[np.uint8]) -> None:
    """Writes a PNG.

    Raises:
        InputError: opencv could not write it.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise InputError(path, "cannot write this picture")


def write_maps(folder: Path, grids: dict[str, OccupancyGrid]) -> list[Path]:
    """Writes ``<name>.png`` for each grid and ``side-by-side.png`` of them all."""
    written = []
    for name, grid in grids.items():
        path = folder / f"{name}.png"
        write_png(path, picture(grid))
        written.append(path)
    path = folder / "side-by-side.png"
    write_png(path, side_by_side(list(grids.values()), list(grids)))
    written.append(path)
    return written
