"""Pictures of a VGM pair: both scans in two colours over the two VGM channels."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2

# BGR colours: previous scan blue-cyan, current scan orange, as in most scan-matching viewers.
PREV_BGR = np.array([255, 170, 40], dtype=np.float32)
CUR_BGR = np.array([30, 140, 255], dtype=np.float32)
BACKGROUND = 18


@dataclass(frozen=True)
class Caption:
    """Text lines drawn above the picture."""

    lines: tuple[str, ...]


def heatmap(vgm: NDArray[np.float32], gamma: float = 0.5) -> NDArray[np.uint8]:
    """Colours a (2, H, W) VGM: channel 0 in the previous scan's colour, 1 in the current's.

    Rows run along +y, so the image is flipped to show +y up. ``gamma`` < 1 lifts faint cells.
    """
    c0 = np.clip(vgm[0], 0, 1) ** gamma
    c1 = np.clip(vgm[1], 0, 1) ** gamma
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
) -> NDArray[np.uint8]:
    """Draws the VGM heatmap, both scans' points and both sensor poses, as a BGR image.

    The view is the square of cells around everything drawn (plus a 1 m margin), scaled up
    to about ``width`` pixels so single cells stay visible.

    Args:
        vgm: (2, size, size) VGM of the pair.
        prev_points: Previous scan's points in its frame.
        cur_points: Current scan's points in its own frame (moved here by ``estimate``).
        estimate: Pose of the current scan in the previous scan's frame.
        resolution: VGM cell edge, metres.
        width: Picture width in pixels, roughly.
        caption: Text lines above the picture.
    """
    size = vgm.shape[-1]
    half = 0.5 * size * resolution
    moved = se2.transform_points(estimate, cur_points)
    i0, i1, j0, j1 = _view(
        np.vstack([prev_points, moved, [[0.0, 0.0], estimate[:2]]]), size, resolution
    )
    scale = max(2, width // (j1 - j0))
    crop = heatmap(vgm[:, i0:i1, j0:j1])
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

    radius = max(1, scale // 4)
    for pts, colour in ((prev_points, PREV_BGR), (moved, CUR_BGR)):
        for u, v in to_px(pts):
            cv2.circle(
                img, (int(u), int(v)), radius, tuple(int(c) for c in colour), -1, cv2.LINE_AA
            )
    for pose, colour in ((np.zeros(3), PREV_BGR), (np.asarray(estimate), CUR_BGR)):
        _draw_pose(img, pose, to_px, px_per_m, tuple(int(c) for c in colour))
    _draw_scale_bar(img, px_per_m)
    if caption is not None:
        img = _add_caption(img, caption)
    return img


def _view(points: NDArray[np.float64], size: int, resolution: float) -> tuple[int, int, int, int]:
    """Rows i0:i1 and columns j0:j1 of the square of cells around ``points`` plus 1 m."""
    half = 0.5 * size * resolution
    lo = np.clip(np.floor((points.min(axis=0) - 1.0 + half) / resolution), 0, size)
    hi = np.clip(np.ceil((points.max(axis=0) + 1.0 + half) / resolution), 0, size)
    side = int(max(hi - lo))
    centre = (lo + hi) / 2
    start = np.clip(np.round(centre - side / 2), 0, size - side).astype(int)
    j0, i0 = int(start[0]), int(start[1])
    return i0, i0 + side, j0, j0 + side


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


def _add_caption(img: NDArray[np.uint8], caption: Caption) -> NDArray[np.uint8]:
    line_h = 22
    bar = np.full((line_h * len(caption.lines) + 12, img.shape[1], 3), 40, dtype=np.uint8)
    for k, text in enumerate(caption.lines):
        cv2.putText(
            bar,
            text,
            (10, 20 + k * line_h),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.55,
            (235, 235, 235),
            1,
            cv2.LINE_AA,
        )
    legend_y = 20
    for text, colour in (("previous", PREV_BGR), ("current", CUR_BGR)):
        x = img.shape[1] - 120
        cv2.circle(bar, (x, legend_y - 5), 6, tuple(int(c) for c in colour), -1, cv2.LINE_AA)
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
        legend_y += line_h
    return np.vstack([bar, img])
