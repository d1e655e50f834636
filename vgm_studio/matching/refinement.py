"""2D point-to-line ICP: the last few millimetres kiss-icp's point-to-point 3D solver leaves.

Gauss-Newton over (x, y, θ) with Huber weights on the point-to-line residuals
r = nᵀ(R·p + t − q), q the nearest target point and n its local line normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.refine_kernel import figures, gauss_newton, line_normals

# The nearest-point grid's cell, metres: about the refinement's gate, so that a query reads
# a 3 × 3 block of cells.
_CELL = 0.3

# Gauss-Newton ends when its update's norm (metres and radians) falls below this.
TOLERANCE = 5e-4


@dataclass(frozen=True)
class Target:
    """A target scan prepared once for many refinements: its points, line normals, and the
    grid of cells its nearest points are found through (``refine_kernel``)."""

    points: NDArray[np.float64]
    # The points and normals sorted by cell (a normal NaN until a refinement meets its
    # point), with the grid the kernels read.
    _cells: tuple[Any, ...] = field(repr=False, compare=False)
    _normals: NDArray[np.float64] = field(repr=False, compare=False)
    _frame: NDArray[np.float64] = field(repr=False, compare=False)

    @property
    def normals(self) -> NDArray[np.float64]:
        """(N, 2) each point's line normal, in the order of ``points``."""
        line_normals(self._cells, self._frame, self._normals)
        normals = np.empty_like(self._normals)
        normals[self._cells[1]] = self._normals
        return normals

    @classmethod
    def build(cls, points: NDArray[np.float64], neighbors: int = 6) -> Target:
        """Args: points (N, 2); neighbors: nearest points used to fit each local line.

        The normals are computed as the refinements meet their points (``refine_kernel``).
        """
        points = np.ascontiguousarray(points, dtype=np.float64)
        origin = points.min(axis=0)
        cell = np.floor((points - origin) / _CELL).astype(np.int64)
        nx, ny = (int(v) + 1 for v in cell.max(axis=0))
        keys = cell[:, 0] * ny + cell[:, 1]
        order = np.argsort(keys, kind="stable")
        unique, first = np.unique(keys[order], return_index=True)
        cells = (
            np.ascontiguousarray(points[order]),
            order.astype(np.int64),
            unique.astype(np.int64),
            np.append(first, len(points)).astype(np.int64),
        )
        frame = np.array([origin[0], origin[1], _CELL, nx, ny, neighbors], dtype=np.float64)
        return cls(points, cells, np.full((len(points), 2), np.nan), frame)


@dataclass(frozen=True)
class Refinement:
    """What the refinement found.

    Attributes:
        estimate: (x, y, θ) of the source scan in the target frame.
        iterations: Gauss-Newton iterations run.
        converged: The last update was below the tolerance.
        inlier_ratio: Share of source points with a correspondence and |r| < inlier distance.
        residual: RMS point-to-line residual of the inliers, in metres.
        covariance: 3×3 covariance of (x, y, θ), σ̂²·(JᵀWJ)⁻¹; None when degenerate.
        paired_ratio: Share of source points with a correspondence (within the gate).
    """

    estimate: NDArray[np.float64]
    iterations: int
    converged: bool
    inlier_ratio: float
    residual: float
    covariance: NDArray[np.float64] | None
    paired_ratio: float = 0.0

    @property
    def fit(self) -> float:
        """Share of the paired points that are inliers: how well the overlap fits, whatever
        its size."""
        return self.inlier_ratio / self.paired_ratio if self.paired_ratio > 0 else 0.0


def refine(
    target: Target,
    source: NDArray[np.float64],
    guess: NDArray[np.float64],
    *,
    max_iterations: int = 30,
    max_distance: float = 0.3,
    inlier_distance: float = 0.05,
    tolerance: float = TOLERANCE,
    degeneracy: float = 0.005,
) -> Refinement:
    """Refines ``guess``, the pose of ``source`` points in the target frame.

    Args:
        target: The prepared target scan.
        source: (N, 2) source points in their own frame.
        guess: Starting pose (x, y, θ).
        max_iterations: Iterations at most.
        max_distance: Nearest-neighbour gate for correspondences, in metres.
        inlier_distance: Residual below which a correspondence counts as an inlier; also the
            Huber threshold.
        tolerance: Stop when the update's norm (metres and radians) falls below this;
            nearest neighbours switching back and forth leave ~0.2 mm steps forever.
        degeneracy: Directions whose curvature is below this share of the largest are left
            where the guess put them (along a featureless corridor, say).
    """
    settings = np.array([max_iterations, max_distance, inlier_distance, tolerance, degeneracy])
    return _refine(target, source, guess, settings)


def _refine(
    target: Target, source: NDArray[np.float64], guess: NDArray[np.float64], settings: Any
) -> Refinement:
    """``refine`` with its settings as the kernels read them (``_settings``)."""
    source = np.ascontiguousarray(source, dtype=np.float64)
    pose, iterations, converged = _settle(target, source, guess, settings)
    max_distance, inlier_distance = float(settings[1]), float(settings[2])
    info, paired, count, sum2 = figures(
        target._cells,
        target._normals,
        target._frame,
        source,
        pose,
        max_distance,
        inlier_distance,
    )
    covariance = _covariance(info, sum2 / (count - 3)) if count > 3 else None
    return Refinement(
        estimate=pose,
        iterations=iterations,
        converged=converged,
        inlier_ratio=count / max(len(source), 1),
        residual=math.sqrt(sum2 / count) if count else float("inf"),
        covariance=covariance,
        paired_ratio=paired / max(len(source), 1),
    )


def _settings(config: MatchConfig, iterate: bool = True) -> NDArray[np.float64]:
    """A matcher's settings as the kernels read them: (iterations at most, the gate, the
    inlier distance, the tolerance, the degeneracy share); no iteration unless ``iterate``."""
    iterations = config.refine_iterations if iterate else 0
    return np.array(
        [iterations, config.refine_distance, config.inlier_distance, TOLERANCE, config.degeneracy]
    )


def _covariance(info: NDArray[np.float64], sigma2: float) -> NDArray[np.float64] | None:
    """σ² (JᵀJ)⁻¹, kept positive semi-definite.

    Along a corridor JᵀJ is near singular and a plain inverse can come out with negative
    variances from rounding; inverting through the eigenvalues gives the weak direction a
    huge but positive variance instead.
    """
    if not np.all(np.isfinite(info)):
        return None
    values, vectors = np.linalg.eigh(info)
    if values[-1] <= 0.0 or values[0] <= values[-1] * 1e-15:
        return None  # singular: no covariance, as the matcher has always said
    return np.asarray(sigma2 * (vectors / values) @ vectors.T, dtype=np.float64)


def _settle(
    target: Target, source: NDArray[np.float64], guess: NDArray[np.float64], settings: Any
) -> tuple[NDArray[np.float64], int, bool]:
    pose, iterations, converged = gauss_newton(
        target._cells,
        target._normals,
        target._frame,
        source,
        np.array(guess, dtype=np.float64),
        settings,
    )
    return pose, int(iterations), bool(converged)


def refine_pose(
    target: Target, source: NDArray[np.float64], guess: NDArray[np.float64], config: MatchConfig
) -> tuple[NDArray[np.float64], int, bool]:
    """``refine_with``'s pose alone, (estimate, iterations, converged): none of the figures it
    computes at the end, for a match that is judged against another target (a loop match
    settles on its submap and is judged against its keyframe)."""
    source = np.ascontiguousarray(source, dtype=np.float64)
    return _settle(target, source, guess, _settings(config))


def refine_with(
    target: Target,
    source: NDArray[np.float64],
    guess: NDArray[np.float64],
    config: MatchConfig,
    iterate: bool = True,
) -> Refinement:
    """``refine`` with a matcher's settings; ``iterate=False`` only judges ``guess`` (its
    inliers, residual and covariance), as the figures of a match are computed."""
    return _refine(target, source, guess, _settings(config, iterate))
