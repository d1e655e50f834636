"""Each VGM channel spread over the neighbourhood its scan cannot resolve, for pictures.

Far from the sensor a scan's points lie a beam spacing apart (range × angle step), wider than
a 5 cm cell: two scans of the same wall, matched perfectly, then hit different cells of it,
and a picture that mixes the raw channels shows a good match as alternating green and magenta
cells. Spread first, mixed after, a cell of one scan lights the other scan's colour too when
the other scan has weight within half that scan's point spacing of it (never less than the
offset a match is still called right within), so agreement reads as agreement at any range.

Tried side by side on right and wrong edges of the demo log and Intel (README), spreading by
the points' own spacing read best: a spacing worked out from the range alone left a right
match's slanted walls green and magenta, a full spacing turned a wrong match's walls white,
and a fixed dilation wide enough for far walls smeared near ones.

The model never sees this: it is for people looking at the VGM.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

# Never spread by less: an offset this small is within what the reference labels call a
# successful match (``ReferenceThresholds.success_xy``), so it should read as agreement.
MIN_SPREAD_M = 0.10
# Nor by more: a return this far from its neighbours is too lone to agree with anything.
MAX_SPREAD_M = 0.50


def point_spacing(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each point's distance to the nearer of its neighbours in beam order.

    That is the beam spacing where the point lies: range times the angle step, longer on a
    wall seen at a slant, which a spacing worked out from the range alone would miss. The
    nearer neighbour, so a point at the edge of an object takes the spacing along it, not
    the jump to whatever lies behind.

    Args:
        points: (N, 2) a scan's points in beam order (as ``Scan.points`` gives them).
    """
    if len(points) < 2:
        return np.full(len(points), np.inf)
    gaps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    nearer: NDArray[np.float64] = np.minimum(np.r_[np.inf, gaps], np.r_[gaps, np.inf])
    return nearer


def _disc(radius: int) -> NDArray[np.uint8]:
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return np.asarray(kernel, dtype=np.uint8)


def spread_channel(
    channel: NDArray[np.float32],
    points: NDArray[np.float64],
    origin: tuple[float, float],
    resolution: float,
) -> NDArray[np.float32]:
    """One channel, each cell's weight spread over a disc of half its points' spacing.

    Half the spacing is what closes the gaps between one scan's returns along a wall (so
    another scan's returns on the wall fall inside), and no more: across the wall the spread
    is as narrow as the spacing allows, so a wrong match still shows two colours.

    Args:
        channel: (rows, cols) one VGM channel or a crop of one; rows run along +y.
        points: (N, 2) the channel's scan points in beam order, in the grid's frame.
        origin: (x, y) in metres of the corner of cell (0, 0).
        resolution: Cell edge, metres.

    Returns:
        (rows, cols): every cell the largest value of the discs that cover it.
    """
    rows, cols = channel.shape
    metres = np.clip(point_spacing(points) / 2, MIN_SPREAD_M, MAX_SPREAD_M)
    radius = np.ceil(metres / resolution - 1e-6).astype(np.int32)
    j = np.floor((points[:, 0] - origin[0]) / resolution).astype(np.int64)
    i = np.floor((points[:, 1] - origin[1]) / resolution).astype(np.int64)
    inside = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
    radii = np.zeros((rows, cols), dtype=np.int32)
    np.maximum.at(radii, (i[inside], j[inside]), radius[inside])
    source = np.ascontiguousarray(channel, dtype=np.float32)
    floor = math.ceil(MIN_SPREAD_M / resolution - 1e-6)
    radii[(source > 0) & (radii == 0)] = floor  # a cell whose points were not given
    out = np.zeros_like(source)
    # One dilation per distinct radius (a dozen at most on a 5 cm grid).
    for r in np.unique(radii[radii > 0]):
        part = np.where(radii == r, source, 0.0).astype(np.float32)
        np.maximum(out, cv2.dilate(part, _disc(int(r))), out=out)
    return out


def spread_pair(
    vgm: NDArray[np.float32],
    origin: tuple[float, float],
    resolution: float,
    clouds: tuple[NDArray[np.float64], NDArray[np.float64]],
) -> NDArray[np.float32]:
    """Both channels of a (cropped) VGM spread by their own scan's spacing.

    Args:
        vgm: (2, rows, cols) VGM or a crop of one; rows run along +y.
        origin: (x, y) in metres of the corner of cell (0, 0) of ``vgm``.
        resolution: Cell edge, metres.
        clouds: The previous scan's points and the current scan's, placed in the grid's
            frame (as the VGM was made), each in beam order.

    Returns:
        (2, rows, cols): channel k spread by scan k's spacing.
    """
    return np.stack(
        [spread_channel(vgm[k], np.asarray(clouds[k]), origin, resolution) for k in range(2)]
    )
