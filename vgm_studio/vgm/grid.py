"""The Validation Grid Map: a per-cell Gaussian, evaluated at the cell centre, times the hit ratio.

For the L×L grid (L = size·r) centred on the origin of the points' frame, cell (i, j) spans
x ∈ [−L/2 + j·r, −L/2 + (j+1)·r) and y ∈ [−L/2 + i·r, −L/2 + (i+1)·r). For a cell holding n ≥ 1
points with mean μ and Σ = (1/n)·Σ(p−μ)(p−μ)ᵀ + σ²·I, its value is
exp(−½ (c−μ)ᵀ Σ⁻¹ (c−μ)) · n / n_max, c being the cell centre and n_max the grid's largest count.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vgm_studio.core import se2
from vgm_studio.core.cpus import usable_threads

DEFAULT_SIZE = 400
DEFAULT_RESOLUTION = 0.05
DEFAULT_SIGMA = 0.02


@dataclass(frozen=True)
class VGMParams:
    """The three numbers a VGM depends on; a model is only valid for the VGMs it was trained on.

    Attributes:
        size: Cells per side.
        resolution: Cell edge, metres.
        sigma: Isotropic covariance regulariser, metres.
    """

    size: int = DEFAULT_SIZE
    resolution: float = DEFAULT_RESOLUTION
    sigma: float = DEFAULT_SIGMA


def grid_cells(
    points: ArrayLike,
    *,
    size: int = DEFAULT_SIZE,
    resolution: float = DEFAULT_RESOLUTION,
    sigma: float = DEFAULT_SIGMA,
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """The occupied cells of one VGM channel: flat indices i·size + j and their values.

    Lets callers write a VGM into any layout (a batch, space-to-depth folded) without a dense
    intermediate. ``grid_map`` documents the arguments.
    """
    _, cell, value = batch_cells([points], size=size, resolution=resolution, sigma=sigma)
    return cell, value


def batch_cells(
    clouds: Sequence[ArrayLike],
    *,
    size: int = DEFAULT_SIZE,
    resolution: float = DEFAULT_RESOLUTION,
    sigma: float = DEFAULT_SIGMA,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32]]:
    """The occupied cells of many VGM channels at once, one channel per point cloud.

    One compiled pass over all the clouds' points (``cell_kernel``) instead of a call per
    cloud. Each channel's values are those ``grid_cells`` gives it alone (same sums in the
    same order; n_max is per channel).

    Args:
        clouds: (N_k, 2) points in metres, one array per channel; empty ones are allowed.
        size: Cells per side.
        resolution: Cell edge in metres.
        sigma: Isotropic regulariser added to every cell's covariance, in metres.

    Returns:
        (channel, cell, value): for every occupied cell the index of its cloud, its flat
        index i·size + j and its value; sorted by channel, then cell.
    """
    # Imported here: numba brings scipy, and ``label`` and ``demo`` check their port before
    # any slow import (VGMParams is read long before a VGM is built).
    from vgm_studio.vgm.cell_kernel import cell_moments

    arrays = [np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in clouds]
    parts = _parts(arrays)
    if len(parts) == 1:
        return cell_moments(arrays, size, resolution, sigma)
    # The kernel lets go of the GIL: a large batch is built in parts at once, and each
    # channel's values do not depend on the others'.
    built = list(
        _pool().map(lambda p: cell_moments(arrays[p[0] : p[1]], size, resolution, sigma), parts)
    )
    return (
        np.concatenate([ch + start for (start, _), (ch, _, _) in zip(parts, built, strict=True)]),
        np.concatenate([cell for _, cell, _ in built]),
        np.concatenate([value for _, _, value in built]),
    )


# Points a part of a batch holds at least: below it the threads' overhead outweighs the gain.
_PART_POINTS = 50_000
_POOLS: dict[int, ThreadPoolExecutor] = {}


def _parts(arrays: Sequence[NDArray[np.float64]]) -> list[tuple[int, int]]:
    """Runs of whole clouds, as many as the usable threads and about equal in points."""
    total = sum(len(a) for a in arrays)
    count = min(usable_threads(), total // _PART_POINTS, len(arrays))
    if count <= 1:
        return [(0, len(arrays))]
    ends = np.searchsorted(np.cumsum([len(a) for a in arrays]), total * np.arange(1, count) / count)
    bounds = [0, *sorted({int(e) + 1 for e in ends if 0 <= e < len(arrays) - 1}), len(arrays)]
    return list(itertools.pairwise(bounds))


def _pool() -> ThreadPoolExecutor:
    threads = usable_threads()
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="vgm")
    return _POOLS[threads]


def grid_map(
    points: ArrayLike,
    *,
    size: int = DEFAULT_SIZE,
    resolution: float = DEFAULT_RESOLUTION,
    sigma: float = DEFAULT_SIGMA,
) -> NDArray[np.float32]:
    """Builds one VGM channel from (N, 2) points.

    Args:
        points: (N, 2) points in metres; those outside the grid are dropped.
        size: Cells per side.
        resolution: Cell edge in metres.
        sigma: Isotropic regulariser added to every cell's covariance, in metres.

    Returns:
        float32 array (size, size); row i runs along y, column j along x.
    """
    out = np.zeros((size, size), dtype=np.float32)
    cell, value = grid_cells(points, size=size, resolution=resolution, sigma=sigma)
    out.ravel()[cell] = value
    return out


def pair_map(
    prev_points: ArrayLike,
    cur_points: ArrayLike,
    estimate: ArrayLike,
    *,
    size: int = DEFAULT_SIZE,
    resolution: float = DEFAULT_RESOLUTION,
    sigma: float = DEFAULT_SIGMA,
) -> NDArray[np.float32]:
    """Builds the two-channel VGM of a matched pair.

    Args:
        prev_points: (N, 2) points of the previous scan, in its own frame.
        cur_points: (M, 2) points of the current scan, in its own frame.
        estimate: (x, y, θ) pose of the current scan in the previous scan's frame.
        size: Cells per side.
        resolution: Cell edge in metres.
        sigma: Isotropic covariance regulariser in metres.

    Returns:
        float32 (2, size, size): channel 0 the previous scan, channel 1 the current scan moved
        into the previous scan's frame (p' = R(θ)·p + t).
    """
    maps = pair_maps(
        [prev_points], [cur_points], [estimate], size=size, resolution=resolution, sigma=sigma
    )
    first: NDArray[np.float32] = maps[0]
    return first


def pair_maps(
    prev_points: Sequence[ArrayLike],
    cur_points: Sequence[ArrayLike],
    estimates: Sequence[ArrayLike],
    *,
    size: int = DEFAULT_SIZE,
    resolution: float = DEFAULT_RESOLUTION,
    sigma: float = DEFAULT_SIGMA,
) -> NDArray[np.float32]:
    """The two-channel VGMs of many matched pairs, built in one pass (``pair_map`` each).

    Returns:
        float32 (K, 2, size, size), pair k's channels as ``pair_map`` gives them.
    """
    clouds: list[ArrayLike] = []
    for prev, cur, est in zip(prev_points, cur_points, estimates, strict=True):
        moved = se2.transform_points(est, np.asarray(cur, dtype=np.float64).reshape(-1, 2))
        clouds += [prev, moved]
    out = np.zeros((len(clouds), size * size), dtype=np.float32)
    channel, cell, value = batch_cells(clouds, size=size, resolution=resolution, sigma=sigma)
    out[channel, cell] = value
    return out.reshape(-1, 2, size, size)
