"""Pictures of a VGM pair: both scans in two colours over the two VGM channels."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.vgm.blend import CUR_HUE, PREV_HUE, blend
from vgm_studio.vgm.spread import spread_pair

# BGR colours: previous scan blue-cyan, current scan orange, as in most scan-matching viewers.
PREV_BGR = np.array([255, 170, 40], dtype=np.float32)
CUR_BGR = np.array([30, 140, 255], dtype=np.float32)
# The current scan placed by the reference pose: where it should be, drawn faint under the rest.
GHOST_BGR = np.array([120, 120, 120], dtype=np.float32)
BACKGROUND = 18
# Every occupied VGM cell is drawn at least this bright (share of its channel colour): a cell's
# value scales with its hit count over the grid's largest, so most cells of a scan sit far below
# 0.1 and vanished into the black background.
MIN_CELL_BRIGHTNESS = 0.5
# Pixels per VGM cell at least: at two, a scan's points covered their own cells and the VGM
# under them could not be seen; at four a point (one pixel) leaves most of its cell showing.
MIN_CELL_PIXELS = 4


@dataclass(frozen=True)
class Caption:
    """Text lines drawn above the picture."""

    lines: tuple[str, ...]
    # Drawn larger, first: the figure a reviewer reads first (inlier ratio and label).
    headline: str | None = None


def heatmap(vgm: NDArray[np.float32], gamma: float = 0.5) -> NDArray[np.uint8]:
    """Colours a (2, H, W) VGM: channel 0 in the previous scan's colour, 1 in the current's.

    Rows run along +y, so the image is flipped to show +y up. ``gamma`` < 1 lifts faint cells,
    and every occupied cell is drawn at least ``MIN_CELL_BRIGHTNESS`` bright; empty cells stay
    background. The colour is scaled to 85% so scan points drawn on top stand out.
    """

    def lift(channel: NDArray[np.float32]) -> NDArray[np.float32]:
        v = np.clip(channel, 0, 1) ** gamma
        lifted = MIN_CELL_BRIGHTNESS + (1 - MIN_CELL_BRIGHTNESS) * v
        return np.where(channel > 0, 0.85 * lifted, 0.0).astype(np.float32)

    c0, c1 = lift(vgm[0]), lift(vgm[1])
    img = BACKGROUND + c0[..., None] * PREV_BGR + c1[..., None] * CUR_BGR
    return np.ascontiguousarray(np.clip(img, 0, 255).astype(np.uint8)[::-1])


def draw_pair(
    vgm: NDArray[np.float32],
    prev_points: NDArray[np.float64],
    cur_points: NDArray[np.float64],
    estimate: NDArray[np.float64],
    *,
    resolution: float,
    width: int = 800,
    caption: Caption | None = None,
    ghost_pose: NDArray[np.float64] | None = None,
) -> NDArray[np.uint8]:
    """Draws the VGM heatmap, both scans' points and both sensor poses, as a BGR image.

    The view is the rectangle of cells around everything drawn (plus a 1 m margin), scaled
    up to about ``width`` pixels and to at least ``MIN_CELL_PIXELS`` a cell, so single cells
    stay visible beside the points. The cells are coloured as in the
    studio's 3D view: green previous, magenta current, white where the other scan has weight
    within its point spacing (``blend.blend`` of ``spread.spread_pair``); those hues are not
    the points' blue and orange, so the cells stay readable under the points.

    Args:
        vgm: (2, size, size) VGM of the pair.
        prev_points: Previous scan's points in its frame.
        cur_points: Current scan's points in its own frame (moved here by ``estimate``).
        estimate: Pose of the current scan in the previous scan's frame.
        resolution: VGM cell edge, metres.
        width: Picture width in pixels, roughly.
        caption: Text lines above the picture.
        ghost_pose: The reference pose of the current scan; when given, the current scan is
            also drawn there, faint grey, so a wrong match shows where it should have landed.
    """
    size = vgm.shape[-1]
    half = 0.5 * size * resolution
    moved = se2.transform_points(estimate, cur_points)
    ghost = None if ghost_pose is None else se2.transform_points(ghost_pose, cur_points)
    extent: list[NDArray[np.float64]] = [
        prev_points,
        moved,
        np.array([[0.0, 0.0], estimate[:2]], dtype=np.float64),
    ]
    if ghost is not None and ghost_pose is not None:
        extent += [ghost, np.asarray(ghost_pose[:2], dtype=np.float64).reshape(1, 2)]
    i0, i1, j0, j1 = _view(np.vstack(extent), size, resolution)
    scale = max(MIN_CELL_PIXELS, width // (j1 - j0))
    origin = (-half + j0 * resolution, -half + i0 * resolution)
    cells = vgm[:, i0:i1, j0:j1]
    spread = spread_pair(cells, origin, resolution, (prev_points, moved))
    crop = np.ascontiguousarray(blend(cells, spread)[::-1, :, ::-1])  # BGR, +y up
    img: NDArray[np.uint8] = np.asarray(
        cv2.resize(
            crop, (crop.shape[1] * scale, crop.shape[0] * scale), interpolation=cv2.INTER_NEAREST
        ),
        dtype=np.uint8,
    )
    px_per_m = scale / resolution
    # Pixel (0, 0) is the top-left corner of cell (i1 − 1, j0): +y is up in the picture.
    x0, y1 = -half + j0 * resolution, -half + i1 * resolution

    def to_px(pts: NDArray[np.float64]) -> NDArray[np.int32]:
        u = (pts[:, 0] - x0) * px_per_m
        v = (y1 - pts[:, 1]) * px_per_m
        return np.round(np.column_stack([u, v])).astype(np.int32)

    # A point drawn as a disc would hide its own cell: one pixel, until cells are big enough
    # that a disc leaves most of the cell (the thing the model sees) visible.
    radius = 0 if scale < 8 else max(1, scale // 8)
    if ghost is not None and ghost_pose is not None:
        # Only on empty background, so it never hides the VGM or the scans it is compared with.
        empty = np.all(img == BACKGROUND, axis=2)
        layer = img.copy()
        _draw_points(layer, to_px(ghost), GHOST_BGR, max(radius, 1), hollow=True)
        img[empty] = layer[empty]
        _draw_pose(img, np.asarray(ghost_pose), to_px, px_per_m, _bgr(GHOST_BGR))
    for pts, colour in ((prev_points, PREV_BGR), (moved, CUR_BGR)):
        _draw_points(img, to_px(pts), colour, radius)
    for pose, colour in ((np.zeros(3), PREV_BGR), (np.asarray(estimate), CUR_BGR)):
        _draw_pose(img, pose, to_px, px_per_m, tuple(int(c) for c in colour))
    _draw_scale_bar(img, px_per_m)
    if caption is not None:
        img = _add_caption(img, caption, ghost=ghost is not None)
    return img


def _bgr(colour: NDArray[np.float32]) -> tuple[int, ...]:
    return tuple(int(c) for c in colour)


def _draw_points(
    img: NDArray[np.uint8],
    px: NDArray[np.int32],
    colour: NDArray[np.float32],
    radius: int,
    hollow: bool = False,
) -> None:
    """Discs of ``radius`` (rings when ``hollow``), or single pixels at radius 0."""
    if radius == 0:
        h, w = img.shape[:2]
        inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        img[px[inside, 1], px[inside, 0]] = colour.astype(np.uint8)
        return
    for u, v in px:
        cv2.circle(img, (int(u), int(v)), radius, _bgr(colour), 1 if hollow else -1, cv2.LINE_AA)


def _view(points: NDArray[np.float64], size: int, resolution: float) -> tuple[int, int, int, int]:
    """Rows i0:i1 and columns j0:j1 of the rectangle of cells around ``points`` plus 1 m."""
    half = 0.5 * size * resolution
    lo = np.clip(np.floor((points.min(axis=0) - 1.0 + half) / resolution), 0, size - 1)
    hi = np.clip(np.ceil((points.max(axis=0) + 1.0 + half) / resolution), lo + 1, size)
    j0, i0 = int(lo[0]), int(lo[1])
    j1, i1 = int(hi[0]), int(hi[1])
    return i0, i1, j0, j1


def _draw_pose(
    img: NDArray[np.uint8],
    pose: NDArray[np.float64],
    to_px: Callable[[NDArray[np.float64]], NDArray[np.int32]],
    px_per_m: float,
    colour: tuple[int, ...],
) -> None:
    tip = se2.transform_points(pose, np.array([[0.5, 0.0], [0.0, 0.0]]))
    (tu, tv), (ou, ov) = to_px(tip)
    cv2.arrowedLine(
        img, (int(ou), int(ov)), (int(tu), int(tv)), (255, 255, 255), 4, cv2.LINE_AA, tipLength=0.35
    )
    cv2.arrowedLine(
        img, (int(ou), int(ov)), (int(tu), int(tv)), colour, 2, cv2.LINE_AA, tipLength=0.35
    )
    cv2.circle(img, (int(ou), int(ov)), max(3, int(0.08 * px_per_m)), colour, -1, cv2.LINE_AA)


def _draw_scale_bar(img: NDArray[np.uint8], px_per_m: float) -> None:
    h = img.shape[0]
    metres = 1 if img.shape[1] < 4 * px_per_m else 2 if img.shape[1] < 12 * px_per_m else 5
    length = round(metres * px_per_m)
    cv2.line(img, (20, h - 20), (20 + length, h - 20), (230, 230, 230), 2)
    cv2.putText(
        img,
        f"{metres} m",
        (20, h - 28),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.5,
        (230, 230, 230),
        1,
        cv2.LINE_AA,
    )


def _add_caption(
    img: NDArray[np.uint8], caption: Caption, ghost: bool = False
) -> NDArray[np.uint8]:
    line_h = 22
    head_h = 34 if caption.headline else 0
    legend = [("previous", PREV_BGR), ("current", CUR_BGR)]
    if ghost:
        legend.append(("reference", GHOST_BGR))
    # The legend has a row of its own under the text: beside it, a long caption line ran
    # under the legend's words.
    rows = len(caption.lines) + 1
    bar = np.full((head_h + line_h * rows + 12, img.shape[1], 3), 40, dtype=np.uint8)
    if caption.headline:
        cv2.putText(
            bar,
            caption.headline,
            (10, 28),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.85,
            (255, 255, 255),
            2,
            cv2.LINE_AA,
        )
    for k, text in enumerate(caption.lines):
        cv2.putText(
            bar,
            text,
            (10, head_h + 20 + k * line_h),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.55,
            (235, 235, 235),
            1,
            cv2.LINE_AA,
        )
    x, legend_y = 16, head_h + 20 + len(caption.lines) * line_h
    for text, colour in legend:
        filled = -1 if colour is not GHOST_BGR else 2
        cv2.circle(bar, (x, legend_y - 5), 6, _bgr(colour), filled, cv2.LINE_AA)
        cv2.putText(
            bar,
            text,
            (x + 12, legend_y),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5,
            (235, 235, 235),
            1,
            cv2.LINE_AA,
        )
        (width, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
        x += 12 + width + 24
    # The cells' hues, as squares (the points are discs).
    both = np.clip(PREV_HUE + CUR_HUE, 0, 1)
    for text, hue in (("cells: previous", PREV_HUE), ("current", CUR_HUE), ("both", both)):
        swatch = _bgr(hue[::-1] * 255)
        cv2.rectangle(bar, (x - 6, legend_y - 11), (x + 6, legend_y + 1), swatch, -1)
        cv2.putText(
            bar, text, (x + 12, legend_y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (235, 235, 235), 1
        )
        (width, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)
        x += 12 + width + 24
    return np.vstack([bar, img])
