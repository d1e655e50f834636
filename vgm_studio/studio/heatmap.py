"""The VGM as the annotator sees it: a two-channel blend in the 3D view, two colormaps in the panel.

In the 3D view the channels are blended additively in green (previous scan) and magenta
(current scan), white where both put weight (``vgm.blend``). By default the hues are mixed
from the channels spread over each scan's point spacing (``vgm.spread``): far from the sensor
two scans of one wall hit different cells, and the raw cells would show a right match as
green and magenta side by side. The cells drawn are the raw ones either way. In the panel the
two channels stand side by side in a perceptual colormap (inferno), cropped to the occupied
cells, with a value bar and the blend's legend.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.vgm.blend import BACKGROUND_RGB, CUR_HUE, GAMMA, PREV_HUE, blend

__all__ = ["BACKGROUND_RGB", "CUR_HUE", "PANEL_WIDTH", "PREV_HUE", "blend", "channels_panel"]

PANEL_WIDTH = 360  # pixels; the panel is about this wide in viser's "large" layout
_TILE = 170
_BAR = 10


def _max_pool(channel: NDArray[np.float32], k: int) -> NDArray[np.float32]:
    """Shrinks by ``k`` keeping each block's maximum: a single-cell hit must not fade out."""
    if k <= 1:
        return channel
    h, w = channel.shape
    padded = np.zeros((math.ceil(h / k) * k, math.ceil(w / k) * k), dtype=np.float32)
    padded[:h, :w] = channel
    blocks: NDArray[np.float32] = padded.reshape(
        padded.shape[0] // k, k, padded.shape[1] // k, k
    ).max(axis=(1, 3))
    return blocks


def _tile(channel: NDArray[np.float32], title: str) -> NDArray[np.uint8]:
    """One channel in inferno on a ``_TILE`` square (+y up), with its title."""
    side = max(channel.shape)
    k = max(1, math.ceil(side / _TILE))
    pooled = _max_pool(channel, k)
    peak = float(pooled.max()) or 1.0
    values = (np.clip(pooled / peak, 0, 1) ** GAMMA * 255).astype(np.uint8)
    coloured = cv2.applyColorMap(values, cv2.COLORMAP_INFERNO)[..., ::-1]
    coloured[pooled <= 0] = BACKGROUND_RGB.astype(np.uint8)
    # Nearest-neighbour up to the tile: cells stay sharp squares, and a 20 m by 3 m corridor
    # crop fills the tile's width instead of sitting in its middle.
    scale = _TILE / max(coloured.shape[:2])
    size = (max(1, round(coloured.shape[1] * scale)), max(1, round(coloured.shape[0] * scale)))
    big = cv2.resize(coloured[::-1], size, interpolation=cv2.INTER_NEAREST)  # rows run along +y
    tile = np.full((_TILE + 16, _TILE, 3), BACKGROUND_RGB, dtype=np.uint8)
    y0 = 16 + (_TILE - big.shape[0]) // 2
    x0 = (_TILE - big.shape[1]) // 2
    tile[y0 : y0 + big.shape[0], x0 : x0 + big.shape[1]] = big
    cv2.putText(tile, title, (2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (220, 220, 220), 1)
    return tile


def _value_bar(width: int) -> NDArray[np.uint8]:
    ramp = np.linspace(0, 255, width).astype(np.uint8)[None, :].repeat(_BAR, axis=0)
    bar = cv2.applyColorMap(ramp, cv2.COLORMAP_INFERNO)[..., ::-1]
    row = np.full((_BAR + 14, width, 3), BACKGROUND_RGB, dtype=np.uint8)
    row[:_BAR] = bar
    font, grey = cv2.FONT_HERSHEY_SIMPLEX, (200, 200, 200)
    cv2.putText(row, "0", (1, _BAR + 11), font, 0.35, grey, 1)
    cv2.putText(row, "cell weight (sqrt)", (width // 2 - 50, _BAR + 11), font, 0.35, grey, 1)
    cv2.putText(row, "max", (width - 24, _BAR + 11), font, 0.35, grey, 1)
    return row


def _legend(width: int) -> NDArray[np.uint8]:
    """The 3D view's blend: which hue means which channel."""
    row = np.full((18, width, 3), BACKGROUND_RGB, dtype=np.uint8)
    entries = (
        ("previous", PREV_HUE),
        ("current", CUR_HUE),
        ("both", np.clip(PREV_HUE + CUR_HUE, 0, 1)),
    )
    x = 2
    for text, hue in entries:
        colour = tuple(int(c) for c in (hue * 255).astype(np.uint8))
        cv2.rectangle(row, (x, 4), (x + 10, 14), colour, -1)
        cv2.putText(row, text, (x + 14, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (220, 220, 220), 1)
        x += 14 + 8 * len(text) + 14
    cv2.putText(row, "in 3D view", (x, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (150, 150, 150), 1)
    return row


def channels_panel(vgm: NDArray[np.float32]) -> NDArray[np.uint8]:
    """The two channels side by side, cropped to their occupied cells, with legend and bar.

    Args:
        vgm: (2, H, W) VGM, already cropped (rows along +y).

    Returns:
        (h, PANEL_WIDTH, 3) RGB.
    """
    gap = PANEL_WIDTH - 2 * _TILE
    tiles = np.concatenate(
        [
            _tile(vgm[0], "previous scan"),
            np.full((_TILE + 16, gap, 3), BACKGROUND_RGB, dtype=np.uint8),
            _tile(vgm[1], "current scan"),
        ],
        axis=1,
    )
    return np.ascontiguousarray(
        np.concatenate([tiles, _value_bar(PANEL_WIDTH), _legend(PANEL_WIDTH)], axis=0)
    )
