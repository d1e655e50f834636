"""What a model reads from an edge: the pair's points, its VGM, an RGB plot, the matcher's figures.

Scans are kept as points (a few kB per edge) and VGMs are built on the fly (0.16 ms a pair):
a dense 2×400×400 float32 VGM is 1.3 MB, too much to keep for every training edge.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import Edge
from vgm_studio.model.context import Context, LocalMapper, log_poses
from vgm_studio.progress import track
from vgm_studio.vgm.grid import VGMParams, batch_cells


@dataclass(frozen=True)
class PairSample:
    """One matched pair, both scans already in the previous scan's frame (float32 points).

    ``spread_xy`` and ``spread_theta`` are log10 of the match estimate's largest position
    variance (m², the top eigenvalue of its xy covariance) and of its heading variance
    (rad²); 0 (1 m², 1 rad²) where the matcher gave no covariance (a degenerate match).
    """

    prev: NDArray[np.float32]
    cur: NDArray[np.float32]
    inlier_ratio: float
    residual: float
    spread_xy: float = 0.0
    spread_theta: float = 0.0


def sample_from_scans(
    prev_points: NDArray[np.float64],
    cur_points: NDArray[np.float64],
    estimate: Sequence[float] | NDArray[np.float64],
    figures: dict[str, object] | None = None,
) -> PairSample:
    """Builds a sample from two scans' points (each in its own frame) and the estimate."""
    figures = figures or {}
    moved = se2.transform_points(np.asarray(estimate, dtype=np.float64), cur_points)
    residual = figures.get("residual")
    spread_xy, spread_theta = _spread(figures.get("covariance"))
    return PairSample(
        prev=np.asarray(prev_points, dtype=np.float32),
        cur=moved.astype(np.float32),
        inlier_ratio=float(figures.get("inlier_ratio", 0.0) or 0.0),  # type: ignore[arg-type]
        residual=float(residual) if isinstance(residual, int | float) else math.inf,
        spread_xy=spread_xy,
        spread_theta=spread_theta,
    )


def _spread(covariance: object) -> tuple[float, float]:
    """log10 of the largest xy variance and of the heading variance, clipped to [-12, 0]."""
    if covariance is None:
        return 0.0, 0.0
    c = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    top = float(np.linalg.eigvalsh(c[:2, :2])[-1])
    values = np.log10(np.clip([top, c[2, 2]], 1e-12, 1.0))
    return float(values[0]), float(values[1])


def load_samples(
    edges: Sequence[Edge],
    scans: EdgeScans | None = None,
    progress: bool = True,
    context: Context | None = None,
) -> list[PairSample]:
    """Reads every edge's two scans (each log once) and returns one sample per edge; with a
    ``context`` each side is its scan's local map (``model/context.py``)."""
    scans = scans or EdgeScans()
    # Only the current log's mapper is kept: its matcher holds every scan it has prepared, and
    # all logs' at once took a training run from 1.3 to 3.4 GB. An edges file lists a log's
    # edges together, so each log's matches are still made once.
    mapper: LocalMapper | None = None
    out = []
    for edge in track(edges, "reading scans", "edge", enabled=progress):
        a, b = scans.scans(edge)
        if context is None or context.neighbours <= 0:
            prev, cur = a.points(), b.points()
        else:
            log = scans.log_for(edge).scans
            if mapper is None or mapper.scans is not log:
                mapper = LocalMapper(log, log_poses(log), context)
            prev, cur = mapper.sides(edge.a, edge.b, edge.estimate)
        out.append(sample_from_scans(prev, cur, edge.estimate, edge.match))
    return out


def _rotate(points: NDArray[np.float32], angle: float) -> NDArray[np.float32]:
    c, s = math.cos(angle), math.sin(angle)
    return (points @ np.array([[c, s], [-s, c]], dtype=np.float32)).astype(np.float32)


@dataclass(frozen=True)
class FoldedCells:
    """The occupied cells of a batch's VGMs in the space-to-depth folded layout.

    Attributes:
        batch: Pairs in the batch.
        side: Folded grid side, size / fold.
        depth: Folded channels, C·fold² (C is 2, or 4 with occupancy).
        pair: For each occupied cell, its pair's index in the batch (ascending).
        position: Its folded position, row·side + column.
        channel: Its folded channel, c·fold² + (i mod fold)·fold + (j mod fold).
        value: Its value (lifted; 1 in the occupancy channels).
    """

    batch: int
    side: int
    depth: int
    pair: NDArray[np.int64]
    position: NDArray[np.int64]
    channel: NDArray[np.int64]
    value: NDArray[np.float32]


def folded_cells(
    samples: Sequence[PairSample],
    params: VGMParams,
    rotations: Sequence[float] | NDArray[np.float64] | None = None,
    fold: int = 1,
    lift: float = 1.0,
    occupancy: bool = False,
) -> FoldedCells:
    """Every occupied cell of a batch's VGMs, all pairs' channels built in one numpy pass;
    ``vgm_batch`` documents the arguments."""
    if params.size % fold:
        raise ValueError(f"VGM size {params.size} is not a multiple of fold {fold}")
    side = params.size // fold
    clouds = []
    for k, s in enumerate(samples):
        prev, cur = s.prev, s.cur
        if rotations is not None and rotations[k]:
            prev, cur = _rotate(prev, rotations[k]), _rotate(cur, rotations[k])
        clouds += [prev, cur]
    slot, cell, value = batch_cells(
        clouds, size=params.size, resolution=params.resolution, sigma=params.sigma
    )
    if lift != 1.0:
        value = value**lift
    i, j = np.divmod(cell, params.size)
    pair, c = np.divmod(slot, 2)
    position = (i // fold) * side + j // fold
    channel = c * fold * fold + (i % fold) * fold + j % fold
    if occupancy:
        pair, position = np.tile(pair, 2), np.tile(position, 2)
        channel = np.r_[channel, channel + 2 * fold * fold]
        value = np.r_[value, np.ones_like(value)]
        # Kept sorted by pair, as without occupancy: the network takes a batch's pairs as
        # slices.
        order = np.argsort(pair, kind="stable")
        pair, position, channel, value = pair[order], position[order], channel[order], value[order]
    depth = (4 if occupancy else 2) * fold * fold
    return FoldedCells(len(samples), side, depth, pair, position, channel, value)


def vgm_batch(
    samples: Sequence[PairSample],
    params: VGMParams,
    rotations: Sequence[float] | NDArray[np.float64] | None = None,
    fold: int = 1,
    lift: float = 1.0,
    occupancy: bool = False,
) -> NDArray[np.float32]:
    """VGMs of a batch; ``rotations`` turn whole pairs (augmentation), ``lift`` raises the
    occupied cells' values to that power, ``occupancy`` adds two channels that are 1 in each
    scan's occupied cells (every point counts alike, as in a plot).

    With ``fold`` f > 1 the result is space-to-depth folded, (B, C·f², size/f, size/f), laid
    out as ``torch.nn.PixelUnshuffle(f)`` would give, but written straight from the occupied
    cells: no dense 400×400 copy to shuffle (C is 2, or 4 with ``occupancy``). ``fold=1``
    gives (B, C, size, size). The array
    is a channels-last view (``.transpose(0, 3, 1, 2)`` of a (B, H, W, C) buffer).
    """
    cells = folded_cells(samples, params, rotations, fold, lift, occupancy)
    # Written channels-last (B, H, W, C) and returned as a (B, C, H, W) view: torch takes it
    # as a channels-last tensor without copying the mostly-zero batch once more.
    out = np.zeros((cells.batch, cells.side, cells.side, cells.depth), dtype=np.float32)
    flat = out.reshape(cells.batch, -1)
    flat[cells.pair, cells.position * cells.depth + cells.channel] = cells.value
    return out.transpose(0, 3, 1, 2)


# Each point a 3-pixel dot, as in a scatter plot.
_DOT = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))


def rgb_plot(
    sample: PairSample, size: int = 200, extent: float = 20.0, rotation: float = 0.0
) -> NDArray[np.uint8]:
    """The Jeong-and-Lee style input: the pair drawn with opencv, previous red, current green.

    Returns (size, size, 3) uint8, RGB, +y up, ``extent`` metres across.
    """
    img = np.zeros((size, size, 3), dtype=np.uint8)
    scale = size / extent
    for pts, channel in ((sample.prev, 0), (sample.cur, 1)):
        p = _rotate(pts, rotation) if rotation else pts
        u = np.round((p[:, 0] + extent / 2) * scale).astype(np.int32)
        v = np.round((extent / 2 - p[:, 1]) * scale).astype(np.int32)
        keep = (u >= 0) & (u < size) & (v >= 0) & (v < size)
        layer = np.zeros((size, size), dtype=np.uint8)
        layer[v[keep], u[keep]] = 255
        img[..., channel] = cv2.dilate(layer, _DOT)
    return img


def rgb_batch(
    samples: Sequence[PairSample],
    size: int = 200,
    rotations: Sequence[float] | NDArray[np.float64] | None = None,
) -> NDArray[np.float32]:
    """RGB plots of a batch as (B, 3, size, size) float32 in [0, 1]."""
    out = np.empty((len(samples), 3, size, size), dtype=np.float32)
    for k, s in enumerate(samples):
        rot = rotations[k] if rotations is not None else 0.0
        out[k] = rgb_plot(s, size, rotation=rot).transpose(2, 0, 1) / 255.0
    return out


def figures_matrix(
    samples: Sequence[PairSample], spread: bool = False, inliers: bool = True
) -> NDArray[np.float64]:
    """(N, 2) matcher figures: inlier ratio and log10 residual; with ``spread`` (N, 4), the
    estimate's log10 position and heading variances after them. Without ``inliers`` the
    first two are left out (the variances alone, or (N, 0))."""
    columns: list[list[float] | NDArray[np.float64]] = []
    if inliers:
        res = np.array([s.residual for s in samples], dtype=np.float64)
        res = np.where(np.isfinite(res), res, 1.0)
        columns += [[s.inlier_ratio for s in samples], np.log10(np.maximum(res, 1e-4))]
    if spread:
        columns += [[s.spread_xy for s in samples], [s.spread_theta for s in samples]]
    if not columns:
        return np.zeros((len(samples), 0), dtype=np.float64)
    return np.column_stack(columns)
