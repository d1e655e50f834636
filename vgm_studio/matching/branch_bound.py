"""Exact correlative search of a scan pose over a window: branch and bound, and brute force.

Correlative scan matching (Olson, "Real-Time Correlative Scan Matching", ICRA 2009) scores every
pose of a discretised search window by how well the scan's end points fall on a likelihood grid,
and keeps the best: it does not need a guess within the basin of an ICP, only a window that holds
the true pose. Branch and bound (Hess et al., "Real-Time Loop Closure in 2D LIDAR SLAM", ICRA
2016, Algorithm 3 and section V) makes it fast and still exact: a block of 2^h × 2^h translations
at one angle is scored on the submap's level-h max grid, which bounds every pose inside it from
above, so a block whose bound is below the best pose found so far is dropped whole.

The discretisation is Cartographer's: angles in steps chosen so that the farthest end point
moves at most one cell per step; each rotated scan is placed on the grid at the guess, and
translations are whole cells added to those indices. The search here walks the tree level by
level, scoring all surviving blocks of a level in one numpy gather (a Python depth-first walk
costs more per node than the gather saves), with greedy descents to the leaves for a good lower
bound early. It returns exactly the pose brute force over the same discretisation returns
(``brute_force``), ties broken towards the lowest (angle, x, y) index. Pure numpy meets the
20 ms per 6 m × 6 m × ±30° query target on one core (``benchmarks/bench_correlative.py``), so
there is no compiled kernel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.matching.submap import PEAK, Submap

# Cell indices gathered per chunk in ``_scores``: 256 KiB of scratch, reused through a search.
_GATHER = 1 << 15


@dataclass(frozen=True)
class SearchWindow:
    """Half-widths of the search around the guess.

    Attributes:
        linear: Half-width in metres, along x and along y (3.0 for a 6 m × 6 m window).
        angular: Half-width in radians.
    """

    linear: float
    angular: float

    def __post_init__(self) -> None:
        if not (self.linear >= 0 and 0 <= self.angular <= math.pi):
            raise ValueError(
                f"a search window needs linear ≥ 0 and 0 ≤ angular ≤ π, not {self.linear}, "
                f"{self.angular}"
            )


@dataclass(frozen=True)
class Hit:
    """The best pose of a correlative search.

    Attributes:
        pose: (x, y, θ) of the scan in the submap frame.
        score: Mean grid value under the scan's points at that pose, 0..1.
        index: (angle, x, y) indices of the pose in the discretised window, from 0.
        evaluated: Candidates (blocks or poses) scored on the way.
    """

    pose: NDArray[np.float64]
    score: float
    index: tuple[int, int, int]
    evaluated: int


@dataclass(frozen=True)
class _Window:
    """A scan discretised over a window, ready for scoring.

    ``base[a, i]`` is the flat index, in the padded levels, of point i's cell at angle a with
    the scan at the guess; a candidate shifted by (x, y) cells reads ``base + x·stride + y``.
    The padding (at least twice the reach) keeps every such index inside the grid; points that
    stay off the unpadded grid for every shift read zero, so they are pointed at an empty cell.
    """

    angles: NDArray[np.float64]
    base: NDArray[np.intp]
    reach: int
    stride: int
    levels: tuple[NDArray[np.uint8], ...]
    guess: NDArray[np.float64]
    resolution: float
    idx: NDArray[np.intp]
    """Scratch for one chunk of candidates' cell indices (``_scores``)."""
    cells: NDArray[np.uint8]
    """…and for the cells they read."""

    def pose(self, a: int, x: int, y: int) -> NDArray[np.float64]:
        r = self.resolution
        return np.array([self.guess[0] + x * r, self.guess[1] + y * r, self.angles[a]])


def angular_step(points: NDArray[np.float64], resolution: float) -> float:
    """Cartographer's angular step: the farthest point moves at most one cell per step."""
    far = float(np.max(np.hypot(points[:, 0], points[:, 1]))) if len(points) else 0.0
    far = max(far, resolution)
    return (1.0 - 1e-3) * math.acos(1.0 - resolution**2 / (2.0 * far**2))


def _discretise(
    submap: Submap,
    points: NDArray[np.float64],
    guess: NDArray[np.float64],
    window: SearchWindow,
    step: float | None,
) -> _Window:
    step = step if step is not None else angular_step(points, submap.resolution)
    n = math.ceil(window.angular / step) if window.angular > 0 else 0
    angles = guess[2] + step * np.arange(-n, n + 1, dtype=np.float64)
    reach = math.floor(window.linear / submap.resolution + 1e-9)
    # Shared between windows of similar reach, as the padded copies are cached per size.
    extra = 64 * math.ceil(2 * reach / 64)
    levels = submap.padded(extra)
    nx, ny = submap.shape
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    wx = guess[0] + c * points[:, 0] - s * points[:, 1]
    wy = guess[1] + s * points[:, 0] + c * points[:, 1]
    cx = np.floor((wx - submap.origin[0]) / submap.resolution).astype(np.int64)
    cy = np.floor((wy - submap.origin[1]) / submap.resolution).astype(np.int64)
    near = (cx + reach >= 0) & (cx - reach < nx) & (cy + reach >= 0) & (cy - reach < ny)
    stride = ny + 2 * extra
    base = np.where(near, (cx + extra) * stride + (cy + extra), reach * stride + reach)
    rows = max(1, _GATHER // max(1, len(points)))
    return _Window(
        angles=angles,
        base=base.astype(np.intp),
        reach=reach,
        stride=stride,
        levels=levels,
        guess=np.asarray(guess, np.float64),
        resolution=submap.resolution,
        idx=np.empty((rows, len(points)), np.intp),
        cells=np.empty((rows, len(points)), np.uint8),
    )


def _scores(
    w: _Window, h: int, a: NDArray[np.intp], x: NDArray[np.intp], y: NDArray[np.intp]
) -> NDArray[np.int32]:
    """Sum of level h under the scan at each candidate (angle a, shifted x, y cells).

    The gather goes through the window's scratch a chunk of candidates at a time. One gather
    of every candidate at once allocates tens of megabytes per call, and the kernel zeroes
    every fresh page: on a newly started machine, whose pages are dear, that was 37% of a
    CSAIL SLAM run's CPU time.
    """
    shift = (x * w.stride + y).astype(np.intp)
    # int32 holds 255 × 8 million points, and sums a quarter faster than int64.
    total = np.empty(len(a), np.int32)
    rows = len(w.idx)
    for start in range(0, len(a), rows):
        stop = min(start + rows, len(a))
        idx, cells = w.idx[: stop - start], w.cells[: stop - start]
        # mode="clip" skips take's bounds check and its buffered copy; the padding keeps
        # every index inside the grid.
        np.take(w.base, a[start:stop], axis=0, out=idx, mode="clip")
        idx += shift[start:stop, None]
        np.take(w.levels[h], idx, out=cells, mode="clip")
        cells.sum(axis=1, dtype=np.int32, out=total[start:stop])
    return total


def _children(
    a: NDArray[np.intp], x: NDArray[np.intp], y: NDArray[np.intp], half: int, reach: int
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """The four half-size blocks of each block, less those starting beyond the window."""
    ca = np.repeat(a, 4)
    cx = (x[:, None] + np.array([0, 0, half, half])).ravel()
    cy = (y[:, None] + np.array([0, half, 0, half])).ravel()
    inside = (cx <= reach) & (cy <= reach)
    return ca[inside], cx[inside], cy[inside]


def _descend(w: _Window, a: int, x: int, y: int, h: int) -> tuple[int, int, int]:
    """Greedy walk from a block to a leaf, always into the best child: a lower bound."""
    ia, ix, iy = np.array([a]), np.array([x]), np.array([y])
    while h > 0:
        ia, ix, iy = _children(ia, ix, iy, 2 ** (h - 1), w.reach)
        h -= 1
        best = int(np.argmax(_scores(w, h, ia, ix, iy)))
        ia, ix, iy = ia[best : best + 1], ix[best : best + 1], iy[best : best + 1]
    return int(ia[0]), int(ix[0]), int(iy[0])


def _leaf_score(w: _Window, leaf: tuple[int, int, int]) -> int:
    a, x, y = (np.array([v]) for v in leaf)
    return int(_scores(w, 0, a, x, y)[0])


def _first_best(
    a: NDArray[np.intp], x: NDArray[np.intp], y: NDArray[np.intp], s: NDArray[np.signedinteger]
) -> int:
    """Index of the highest score, ties to the lowest (angle, x, y), as brute force picks."""
    top = np.flatnonzero(s == s.max())
    order = np.lexsort((y[top], x[top], a[top]))
    return int(top[order[0]])


def branch_and_bound(
    submap: Submap,
    points: NDArray[np.float64],
    guess: NDArray[np.float64],
    window: SearchWindow,
    *,
    step: float | None = None,
    min_score: float = 0.0,
) -> Hit | None:
    """The best pose of ``points`` on the submap within ``window`` of ``guess``; exact.

    Returns None when there are no points or no pose reaches ``min_score``.
    """
    if len(points) == 0:
        return None
    w = _discretise(submap, points, np.asarray(guess, np.float64), window, step)
    side = 2 * w.reach + 1
    height = min(submap.depth, math.ceil(math.log2(side)))
    starts = np.arange(-w.reach, w.reach + 1, 2**height)
    ga, gx, gy = np.meshgrid(np.arange(len(w.angles)), starts, starts, indexing="ij")
    a, x, y = ga.ravel(), gx.ravel(), gy.ravel()
    bound = _scores(w, height, a, x, y)
    evaluated = len(a)
    floor = math.ceil(min_score * PEAK * len(points))
    # One greedy descent from the best block: on Intel's loop searches, descents from the
    # best three cost more than the blocks they pruned (1.6 against 1.7 ms a search).
    k = int(np.argmax(bound))
    best = max(floor, _leaf_score(w, _descend(w, a[k], x[k], y[k], height)))
    for h in range(height, 0, -1):
        keep = bound >= best
        a, x, y = _children(a[keep], x[keep], y[keep], 2 ** (h - 1), w.reach)
        bound = _scores(w, h - 1, a, x, y)
        evaluated += len(a)
        if len(a) == 0:
            return None
        if h > 1:
            k = int(np.argmax(bound))
            leaf = _descend(w, a[k], x[k], y[k], h - 1)
            best = max(best, _leaf_score(w, leaf))
    keep = bound >= best
    if not keep.any():
        return None
    a, x, y, bound = a[keep], x[keep], y[keep], bound[keep]
    i = _first_best(a, x, y, bound)
    return Hit(
        pose=w.pose(int(a[i]), int(x[i]), int(y[i])),
        score=float(bound[i]) / (PEAK * len(points)),
        index=(int(a[i]), int(x[i]) + w.reach, int(y[i]) + w.reach),
        evaluated=evaluated,
    )


def brute_force(
    submap: Submap,
    points: NDArray[np.float64],
    guess: NDArray[np.float64],
    window: SearchWindow,
    *,
    step: float | None = None,
) -> Hit | None:
    """Scores every pose of the discretised window; the reference ``branch_and_bound`` must
    equal (slow: for tests and the benchmark's speed ratio)."""
    if len(points) == 0:
        return None
    w = _discretise(submap, points, np.asarray(guess, np.float64), window, step)
    offsets = np.arange(-w.reach, w.reach + 1)
    gx, gy = (g.ravel() for g in np.meshgrid(offsets, offsets, indexing="ij"))
    best: tuple[int, int, int, int] | None = None
    for a in range(len(w.angles)):
        s = _scores(w, 0, np.full(len(gx), a), gx, gy)
        i = int(np.argmax(s))
        if best is None or s[i] > best[0]:
            best = (int(s[i]), a, int(gx[i]), int(gy[i]))
    assert best is not None
    score, a, x, y = best
    return Hit(
        pose=w.pose(a, x, y),
        score=score / (PEAK * len(points)),
        index=(a, x + w.reach, y + w.reach),
        evaluated=len(w.angles) * len(gx),
    )


def thin_points(points: NDArray[np.float64], spacing: float) -> NDArray[np.float64]:
    """Keeps the first point of every ``spacing``-sized square cell, in scan order."""
    if spacing <= 0 or len(points) == 0:
        return points
    keys = np.floor(points / spacing).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]
