"""A likelihood grid of points in one frame, with the max grids branch and bound searches.

The correlative matcher (``correlative.py``) scores a scan pose by summing grid values under the
scan's end points. Its branch and bound needs, for every height h, an upper bound of that sum
over a 2^h × 2^h block of translations: level h of ``Submap.levels`` holds, for every cell, the
largest level-0 value of the 2^h × 2^h block of cells starting there (Cartographer's
``PrecomputationGrid2D``; Hess et al., "Real-Time Loop Closure in 2D LIDAR SLAM", ICRA 2016,
section V.C). Summing level h under the scan shifted to a block's corner therefore bounds every
pose inside the block from above.

Values are quantised to uint8 (0..255) so that scores are integer sums: exact, independent of
summation order, and the same whether branch and bound or brute force adds them up.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.refinement import Target
from vgm_studio.matching.surface import stretch_points

# Highest value of the grid: a cell holding an end point.
PEAK = 255

# Empty cells around the levels as a search reads them (``Submap.padded``): enough for a
# window of ±32 cells (1.6 m at 5 cm), the sequential matches' and most loops'.
SEARCH_PADDING = 64


@dataclass(frozen=True)
class Submap:
    """A likelihood grid of points placed in one frame, with its multi-resolution max grids.

    Cell (i, j) of every level covers x ∈ [origin_x + i·resolution, … + resolution), and the
    same along y. The grid is padded with ``2^depth`` empty cells on every side, so a block of any
    level that starts outside the data still sees it; indices clipped into the outermost cells
    read zero on every level.

    Attributes:
        points: (N, 2) the points the grid was made from, in the submap frame.
        resolution: Cell edge, metres.
        origin: (x, y) of the lower corner of cell (0, 0), metres.
        levels: Level h is the max over the 2^h × 2^h block starting at each cell; level 0 is
            the likelihood grid itself. uint8 arrays indexed [i_x, i_y].
        sigma: Standard deviation of the likelihood around each point, metres.
        normal_neighbors: Neighbours used to fit each point's local line for the refinement.
    """

    points: NDArray[np.float64]
    resolution: float
    origin: NDArray[np.float64]
    levels: tuple[NDArray[np.uint8], ...]
    sigma: float
    normal_neighbors: int = 6
    _target: list[Target] = field(default_factory=list, repr=False, compare=False)
    _padded: dict[int, NDArray[np.uint8]] = field(default_factory=dict, repr=False, compare=False)

    @property
    def depth(self) -> int:
        """The highest precomputed level."""
        return len(self.levels) - 1

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.levels[0].shape[0]), int(self.levels[0].shape[1]))

    @classmethod
    def from_points(
        cls,
        points: NDArray[np.float64],
        resolution: float = 0.05,
        *,
        sigma: float | None = None,
        depth: int = 7,
        normal_neighbors: int = 6,
        stretches: NDArray[np.float64] | None = None,
    ) -> Submap:
        """Builds the grid and its max levels from points in the submap frame.

        Args:
            points: (N, 2) end points, N ≥ 1.
            resolution: Cell edge, metres.
            sigma: Standard deviation of the Gaussian likelihood around each point, metres;
                defaults to the resolution (a point's own cell scores 255, its neighbours ~155).
            depth: Highest level to precompute; branch and bound over windows wider than
                2^depth cells starts from several top blocks.
            normal_neighbors: Neighbours used to fit local lines for the refinement.
            stretches: (M, 2) more points the grid is drawn from, which the refinement does
                not match against: the surfaces between a scan's end points (``surface.py``).

        Raises:
            ValueError: No points, a resolution ≤ 0 or a negative depth.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if len(pts) == 0:
            raise ValueError("a submap needs at least one point")
        grid_pts = pts
        if stretches is not None:
            grid_pts = np.concatenate([pts, np.asarray(stretches, np.float64).reshape(-1, 2)])
        if resolution <= 0 or depth < 0:
            raise ValueError("resolution must be positive and depth non-negative")
        sig = float(sigma) if sigma is not None else resolution
        pad = 2**depth + math.ceil(3.0 * sig / resolution) + 1
        lo = np.floor(grid_pts.min(axis=0) / resolution) * resolution - pad * resolution
        cells = np.floor((grid_pts - lo) / resolution).astype(np.intp)
        shape = (int(cells[:, 0].max()) + pad + 1, int(cells[:, 1].max()) + pad + 1)
        # The levels are made inside the padding a search reads them with (``padded``), so
        # the first search copies nothing (a copy of every level was 7 % of an Intel run).
        extra = SEARCH_PADDING
        padded = np.zeros((depth + 1, shape[0] + 2 * extra, shape[1] + 2 * extra), np.uint8)
        levels = padded[:, extra : extra + shape[0], extra : extra + shape[1]]
        box = _likelihood(cells, shape, sig / resolution, out=levels[0])
        _max_levels(levels, box)
        return cls(
            points=pts,
            resolution=float(resolution),
            origin=lo,
            levels=tuple(levels),
            sigma=sig,
            normal_neighbors=normal_neighbors,
            _padded={extra: padded.reshape(depth + 1, -1)},
        )

    @classmethod
    def from_scans(
        cls,
        scans: Sequence[Scan],
        poses: NDArray[np.float64],
        resolution: float = 0.05,
        *,
        max_range: float = 30.0,
        surfaces: bool = False,
        **kw: float | int | None,
    ) -> Submap:
        """Places several scans in one frame and builds their grid.

        Args:
            scans: The scans (keyframes around the loop target, say).
            poses: (M, 3) each scan's pose in the submap frame.
            resolution: Cell edge, metres.
            max_range: Readings farther than this are left out.
            surfaces: Draw in the stretches between neighbouring end points on one surface
                (``surface.py``), for a search over steps of metres between single scans.
                Submaps of several keyframes a metre or less apart sample their walls from
                several places, and there the stretches measured worse (freiburg-campus
                0.089 → 0.110 m drawn into the loops' submaps, → 0.113 into the sequential
                ones; Örebro's sequential submaps 0.052 → 0.079 m).
            **kw: Passed on to ``from_points`` (sigma, depth, normal_neighbors).

        Raises:
            ValueError: Scans and poses differ in number, or no scan has a point in range.
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(poses) != len(scans):
            raise ValueError(f"{len(scans)} scans but {len(poses)} poses")
        parts, stretches = [], []
        for scan, pose in zip(scans, poses, strict=True):
            pts = scan.points()
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= max_range]
            parts.append(se2.transform_points(pose, pts))
            if surfaces:
                between = stretch_points(scan, max_range, resolution / 2)
                stretches.append(se2.transform_points(pose, between))
        merged = np.concatenate(parts) if parts else np.empty((0, 2))
        drawn = np.concatenate(stretches) if stretches else np.empty((0, 2))
        return cls.from_points(merged, resolution, stretches=drawn, **kw)  # type: ignore[arg-type]

    def target(self) -> Target:
        """The points prepared for point-to-line refinement (grid of cells, normals), built once."""
        if not self._target:
            self._target.append(Target.build(self.points, self.normal_neighbors))
        return self._target[0]

    def padded(self, extra: int) -> NDArray[np.uint8]:
        """The levels with ``extra`` more empty cells on every side (cell (i, j) becomes
        (i + extra, j + extra)), each flattened into a row of one (depth + 1, cells) array,
        kept for the next query that needs the same padding.

        Padding is exact: every block starting in it covers only empty cells, as the grid's own
        padding is wider than the largest block.
        """
        if extra not in self._padded:
            # Each level written once into its padded place: padding each and then stacking
            # them copied every level twice (0.6 ms a submap, 1.5 % of an Intel run).
            height, width = self.levels[0].shape
            out = np.zeros(
                (len(self.levels), height + 2 * extra, width + 2 * extra), dtype=np.uint8
            )
            for k, level in enumerate(self.levels):
                out[k, extra : extra + height, extra : extra + width] = level
            self._padded[extra] = out.reshape(len(self.levels), -1)
        return self._padded[extra]

    def padding_for(self, wanted: int) -> int:
        """The padding to read with where at least ``wanted`` is needed: the smallest one
        already made that is wide enough, else ``wanted``. Wider padding reads the same
        values, and a second copy of every level for a narrower window (the score surface's
        around a loop's match) added 170 MB to an Intel run's peak."""
        return min((e for e in self._padded if e >= wanted), default=wanted)

    def cells(self, points: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Cell indices (i_x, i_y) of points in the submap frame, not clipped."""
        c = np.floor((np.asarray(points, dtype=np.float64) - self.origin) / self.resolution)
        return c[:, 0].astype(np.intp), c[:, 1].astype(np.intp)


def _likelihood(
    cells: NDArray[np.intp],
    shape: tuple[int, int],
    sigma_cells: float,
    out: NDArray[np.uint8],
) -> tuple[tuple[int, int], tuple[int, int]]:
    """Writes into ``out`` (zeros of ``shape``) the Gaussian of each cell's distance to the
    nearest occupied one, quantised to 0..PEAK; returns the box of cells within 3σ of a point,
    ((lo_x, lo_y), (hi_x, hi_y)), hi exclusive: every cell outside it stays zero."""
    # Only cells within 3σ of a point score: the transform runs on the points' box and that
    # margin, not on the padding for branch and bound's top blocks (most of a small
    # submap). The chamfer distance is a norm whose shortest paths stay in the box of their
    # ends, so the cropped transform equals the full one inside the crop.
    margin = math.ceil(3.0 * sigma_cells) + 1
    lo = np.maximum(cells.min(axis=0) - margin, 0)
    hi = np.minimum(cells.max(axis=0) + margin + 1, shape)
    (x0, y0), (x1, y1) = (int(lo[0]), int(lo[1])), (int(hi[0]), int(hi[1]))
    free = np.full((x1 - x0, y1 - y0), 255, dtype=np.uint8)
    free[cells[:, 0] - x0, cells[:, 1] - y0] = 0
    # The Euclidean distance in cells from every cell to the nearest occupied one, by the
    # 5×5 chamfer: within the 3σ that count it is within 0.1 cell of the exact transform,
    # and 3× faster (the transform was 8% of an Intel SLAM run).
    dist = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_5)
    # Cut at 3σ, so the padding around the data (wider than 3σ) is exactly zero. The
    # Gaussian is taken of the cells within it only: along a scan's walls a few in ten.
    near = dist <= 3.0 * sigma_cells
    value = np.zeros(dist.shape, dtype=np.uint8)
    value[near] = np.rint(PEAK * np.exp(-0.5 * (dist[near] / max(sigma_cells, 1e-9)) ** 2))
    out[x0:x1, y0:y1] = value
    return (x0, y0), (x1, y1)


def _max_levels(levels: NDArray[np.uint8], box: tuple[tuple[int, int], tuple[int, int]]) -> None:
    """Fills levels 1.. of ``levels`` (zeros, level 0 given): level h is the max over the
    2^h × 2^h block starting at each cell.

    Each level is two shifted maxima of the one below (a 2^h block is four 2^(h−1) blocks),
    with zeros beyond the grid's far edges. Level 0 is zero outside ``box``, so level h is
    zero but for blocks that reach into it: cells from 2^h − 1 before the box to its end.
    Only those are computed (a submap's padding is wider than the data on a small one).
    """
    (x0, y0), (x1, y1) = box
    for h in range(1, len(levels)):
        s = 2 ** (h - 1)
        prev, here = levels[h - 1], levels[h]
        a, b = max(x0 - 2 * s + 1, 0), max(y0 - 2 * s + 1, 0)
        # Past the box's end level h - 1 is zero, and the grid's padding is wider than s.
        along_x = np.maximum(prev[a:x1, b : y1 + s], prev[a + s : x1 + s, b : y1 + s])
        np.maximum(along_x[:, : y1 - b], along_x[:, s:], out=here[a:x1, b:y1])
