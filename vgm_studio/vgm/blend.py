"""The two VGM channels mixed into one picture: green previous, magenta current, white both.

Blended additively: where both scans put weight the cell turns white, where only one does it
keeps that scan's hue. Those hues are not the points' blue and orange (``render``), so the
cells stay readable under the points. The studio's 3D view and ``vgm-studio vgm`` draw it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

# RGB, 0..1: additive, so both channels at full weight give white.
PREV_HUE = np.array([0.1, 1.0, 0.25], dtype=np.float32)
CUR_HUE = np.array([1.0, 0.1, 0.9], dtype=np.float32)
BACKGROUND_RGB = np.array([17, 17, 17], dtype=np.float32)
# A cell's value is its share of the channel's largest, and most cells sit far below 0.1:
# the square root and a floor keep every occupied cell visible; empty cells stay background.
GAMMA = 0.5
FLOOR = 0.35


def lift(channel: NDArray[np.float32]) -> NDArray[np.float32]:
    """A channel's values as brightness in [FLOOR, 1] where occupied, 0 elsewhere."""
    peak = float(channel.max())
    if peak <= 0:
        return np.zeros_like(channel)
    v = np.clip(channel / peak, 0, 1) ** GAMMA
    return np.where(channel > 0, FLOOR + (1 - FLOOR) * v, 0.0).astype(np.float32)


def blend(vgm: NDArray[np.float32], spread: NDArray[np.float32] | None = None) -> NDArray[np.uint8]:
    """(2, H, W) VGM → (H, W, 3) RGB, row 0 at the grid's first row (-y).

    Args:
        vgm: The VGM (or a crop): its occupied cells are the ones drawn.
        spread: The same channels spread (``spread.spread_pair``); when given, the hues are
            mixed from it, so a cell is white when the other scan has weight nearby.
    """
    mix = vgm if spread is None else spread
    a, b = lift(mix[0]), lift(mix[1])
    rgb = a[..., None] * PREV_HUE + b[..., None] * CUR_HUE
    lit = np.clip(rgb, 0, 1) * 255.0
    occupied = (vgm[0] > 0) | (vgm[1] > 0)
    out = np.where(occupied[..., None], lit, BACKGROUND_RGB)
    return np.ascontiguousarray(out.astype(np.uint8))
