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
translations are whole cells added to those indices. The tree is walked depth first, best
child first, in a compiled kernel (``bb_kernel``). It returns exactly the pose brute force over
the same discretisation returns (``brute_force``), ties broken towards the lowest
(angle, x, y) index.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.matching import bb_kernel
from vgm_studio.matching.submap import PEAK, Submap

# Cell indices gathered per chunk in ``_scores``: 256 KiB of scratch, reused through a call.
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
    levels: NDArray[np.uint8]
    """(depth + 1, cells): the padded levels, each flattened."""
    guess: NDArray[np.float64]
    resolution: float

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
    if step is None:
        # A window of one heading has no step to take.
        step = angular_step(points, submap.resolution) if window.angular > 0 else 0.0
    n = math.ceil(window.angular / step) if window.angular > 0 else 0
    angles = guess[2] + step * np.arange(-n, n + 1, dtype=np.float64)
    reach = math.floor(window.linear / submap.resolution + 1e-9)
    # Shared between windows of similar reach, as the padded copies are cached per size.
    extra = submap.padding_for(64 * math.ceil(2 * reach / 64))
    levels = submap.padded(extra)
    grid = (submap.origin, submap.resolution, submap.shape)
    base = bb_kernel.cells(points, angles, guess, grid, reach, extra)
    stride = submap.shape[1] + 2 * extra
    return _Window(
        angles=angles,
        base=base,
        reach=reach,
        stride=stride,
        levels=levels,
        guess=np.asarray(guess, np.float64),
        resolution=submap.resolution,
    )


def _scores(
    w: _Window, h: int, a: NDArray[np.intp], x: NDArray[np.intp], y: NDArray[np.intp]
) -> NDArray[np.int32]:
    """Sum of level h under the scan at each candidate (angle a, shifted x, y cells), in numpy:
    what ``brute_force`` scores every pose with.

    The gather goes through scratch a chunk of candidates at a time (``_chunk_rows``). One
    gather of every candidate at once allocates tens of megabytes per call, and the kernel
    zeroes every fresh page: on a newly started machine, whose pages are dear, that was 37%
    of a CSAIL SLAM run's CPU time when branch and bound scored this way.
    """
    shift = (x * w.stride + y).astype(np.intp)
    # int32 holds 255 × 8 million points, and sums a quarter faster than int64.
    total = np.empty(len(a), np.int32)
    rows = _chunk_rows(w.base.shape[1])
    scratch_idx = np.empty((rows, w.base.shape[1]), np.intp)
    scratch_cells = np.empty((rows, w.base.shape[1]), np.uint8)
    for start in range(0, len(a), rows):
        stop = min(start + rows, len(a))
        idx, cells = scratch_idx[: stop - start], scratch_cells[: stop - start]
        # mode="clip" skips take's bounds check and its buffered copy; the padding keeps
        # every index inside the grid.
        np.take(w.base, a[start:stop], axis=0, out=idx, mode="clip")
        idx += shift[start:stop, None]
        np.take(w.levels[h], idx, out=cells, mode="clip")
        cells.sum(axis=1, dtype=np.int32, out=total[start:stop])
    return total


def _chunk_rows(points: int) -> int:
    """Candidates per chunk of ``_scores``' gather, for a scan of ``points`` points."""
    return max(1, _GATHER // max(1, points))


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
    height = min(submap.depth, math.ceil(math.log2(2 * w.reach + 1)))
    floor = math.ceil(min_score * PEAK * len(points))
    found = bb_kernel.search(w.levels, w.base, w.stride, w.reach, height, floor)
    if found is None:
        return None
    score, a, x, y, evaluated = found
    return Hit(
        pose=w.pose(a, x, y),
        score=score / (PEAK * len(points)),
        index=(a, x + w.reach, y + w.reach),
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


def surface(
    submap: Submap,
    points: NDArray[np.float64],
    pose: NDArray[np.float64],
    window: SearchWindow,
    *,
    step: float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int32]]:
    """Every pose of the discretised window around ``pose`` scored, as ``brute_force`` scores
    them: the headings (radians), the shifts (metres, the same along x and y) and the scores
    (sums of grid values, ``PEAK`` a point on an end point), indexed [heading, x, y]."""
    w = _discretise(submap, points, np.asarray(pose, np.float64), window, step)
    # Compiled: a match's spread scores two such surfaces (``response.py``), and the numpy
    # gather's index grids and passes cost more than the sums over so few poses.
    scores = bb_kernel.window_scores(w.levels[0], w.base, w.reach, w.stride)
    offsets = np.arange(-w.reach, w.reach + 1, dtype=np.float64)
    return w.angles, offsets * submap.resolution, scores


def thin_points(points: NDArray[np.float64], spacing: float) -> NDArray[np.float64]:
    """Keeps the first point of every ``spacing``-sized square cell, in scan order."""
    if spacing <= 0 or len(points) == 0:
        return points
    keys = np.floor(points / spacing).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]
