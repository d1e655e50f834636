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


Segment = tuple[NDArray[np.float64], NDArray[np.float64], str]


def edges_picture(
    grid: OccupancyGrid, segments: Sequence[Segment], colours: dict[str, tuple[int, int, int]]
) -> NDArray[np.uint8]:
    """The map in colour with edges drawn on it and a legend of their kinds with counts.

    Args:
        grid: The map.
        segments: (start xy, end xy, kind) of each edge, in world metres.
        colours: RGB of each kind, in legend order; kinds without a segment are left out.
    """
    image = cv2.cvtColor(picture(grid), cv2.COLOR_GRAY2BGR)
    height = image.shape[0]

    def pixel(xy: NDArray[np.float64]) -> tuple[int, int]:
        col = (xy[0] - grid.origin[0]) / grid.resolution
        row = (xy[1] - grid.origin[1]) / grid.resolution
        return round(float(col)), round(float(height - 1 - row))

    counts = {kind: sum(s[2] == kind for s in segments) for kind in colours}
    # Kept edges last, so that a rejected loop does not hide under the kept ones.
    for start, end, kind in sorted(segments, key=lambda s: list(colours).index(s[2])):
        r, g, b = colours[kind]
        cv2.line(image, pixel(start), pixel(end), (b, g, r), 1, cv2.LINE_AA)
    shown = [k for k in colours if counts[k]]
    box_h = 8 + 22 * len(shown)
    cv2.rectangle(image, (0, 0), (300, box_h), (255, 255, 255), -1)
    for i, kind in enumerate(shown):
        r, g, b = colours[kind]
        y = 20 + 22 * i
        cv2.line(image, (8, y - 5), (36, y - 5), (b, g, r), 3)
        text = f"{kind} ({counts[kind]})"
        cv2.putText(image, text, (44, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 0, 1, cv2.LINE_AA)
    return np.asarray(image, dtype=np.uint8)


def write_png(path: Path, image: NDArray[np.uint8]) -> None:
    """Writes a PNG.

    Raises:
        InputError: opencv could not write it.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise InputError(path, "cannot write this picture")


def write_maps(
    folder: Path,
    grids: dict[str, OccupancyGrid],
    edges: tuple[str, Sequence[Segment], dict[str, tuple[int, int, int]]] | None = None,
) -> list[Path]:
    """Writes ``<name>.png`` for each grid and ``side-by-side.png`` of them all, and with
    ``edges`` (map name, segments, colours) ``edges.png``: that map with the edges and a legend.
    """
    written = []
    if edges is not None:
        name, segments, colours = edges
        path = folder / "edges.png"
        write_png(path, edges_picture(grids[name], segments, colours))
        written.append(path)
    for name, grid in grids.items():
        path = folder / f"{name}.png"
        write_png(path, picture(grid))
        written.append(path)
    path = folder / "side-by-side.png"
    write_png(path, side_by_side(list(grids.values()), list(grids)))
    written.append(path)
    return written
