"""2D point-to-line ICP: the last few millimetres kiss-icp's point-to-point 3D solver leaves.

Gauss-Newton over (x, y, θ) with Huber weights on the point-to-line residuals
r = nᵀ(R·p + t − q), q the nearest target point and n its local line normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from vgm_studio.core import se2
from vgm_studio.matching.config import MatchConfig


@dataclass(frozen=True)
class Target:
    """A target scan prepared once for many refinements: its points, k-d tree and line normals."""

    points: NDArray[np.float64]
    tree: cKDTree
    normals: NDArray[np.float64]

    @classmethod
    def build(cls, points: NDArray[np.float64], neighbors: int = 6) -> Target:
        """Args: points (N, 2); neighbors: nearest points used to fit each local line."""
        tree = cKDTree(points)
        k = min(neighbors, len(points))
        _, idx = tree.query(points, k=k)
        nb = points[np.asarray(idx).reshape(len(points), k)]
        centred = nb - nb.mean(axis=1, keepdims=True)
        sxx = np.einsum("nk,nk->n", centred[..., 0], centred[..., 0])
        syy = np.einsum("nk,nk->n", centred[..., 1], centred[..., 1])
        sxy = np.einsum("nk,nk->n", centred[..., 0], centred[..., 1])
        # Direction of the local line is the principal axis; the normal is perpendicular to it.
        phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
        normals = np.stack([-np.sin(phi), np.cos(phi)], axis=1)
        return cls(points=points, tree=tree, normals=normals)


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


def _residuals(
    target: Target, source: NDArray[np.float64], pose: NDArray[np.float64], max_distance: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    moved = se2.transform_points(pose, source)
    dist, idx = target.tree.query(moved, k=1, distance_upper_bound=max_distance)
    found = np.isfinite(dist)
    idx = np.where(found, idx, 0)
    n = target.normals[idx]
    r = np.einsum("ij,ij->i", n, moved - target.points[idx])
    return r, n, moved, found


# Radians are scaled to metres at this lever arm when comparing curvatures across x, y, θ.
_LEVER = 5.0


def _constrained_step(
    h: NDArray[np.float64], g: NDArray[np.float64], degeneracy: float
) -> NDArray[np.float64] | None:
    """Gauss-Newton step restricted to well-constrained directions (solution remapping)."""
    scale = np.array([1.0, 1.0, 1.0 / _LEVER])
    hs = h * np.outer(scale, scale)
    gs = g * scale
    try:
        lam, vec = np.linalg.eigh(hs)
    except np.linalg.LinAlgError:
        return None
    if lam[-1] <= 0:
        return None
    keep = lam > degeneracy * lam[-1]
    step = -(vec[:, keep] @ ((vec[:, keep].T @ gs) / lam[keep]))
    return np.asarray(step * scale, dtype=np.float64)


def refine(
    target: Target,
    source: NDArray[np.float64],
    guess: NDArray[np.float64],
    *,
    max_iterations: int = 30,
    max_distance: float = 0.3,
    inlier_distance: float = 0.05,
    tolerance: float = 5e-4,
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
    pose = np.asarray(guess, dtype=np.float64).copy()
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 - the count is reported
        r, n, moved, found = _residuals(target, source, pose, max_distance)
        if found.sum() < 3:
            break
        r, n, moved = r[found], n[found], moved[found]
        jac = _jacobian(n, moved - pose[:2])
        w = np.minimum(1.0, inlier_distance / np.maximum(np.abs(r), 1e-12))
        h = jac.T @ (jac * w[:, None])
        g = jac.T @ (w * r)
        delta = _constrained_step(h, g, degeneracy)
        if delta is None:
            break
        pose = pose + delta
        pose[2] = float(se2.wrap_angle(pose[2]))
        if np.linalg.norm(delta) < tolerance:
            converged = True
            break
    return _judged(target, source, pose, max_distance, inlier_distance, it, converged)


def _jacobian(n: NDArray[np.float64], rel: NDArray[np.float64]) -> NDArray[np.float64]:
    """d(residual)/d(x, y, θ) of point-to-line residuals with normals ``n``, at points ``rel``
    from the pose's origin: the parameters are (x, y, θ) themselves, so d(moved)/dθ is
    (moved − t) turned by 90°."""
    return np.column_stack([n[:, 0], n[:, 1], n[:, 1] * rel[:, 0] - n[:, 0] * rel[:, 1]])


def _judged(
    target: Target,
    source: NDArray[np.float64],
    pose: NDArray[np.float64],
    max_distance: float,
    inlier_distance: float,
    iterations: int,
    converged: bool,
) -> Refinement:
    """The refined pose with its inliers, residual and covariance."""
    r, n, moved, found = _residuals(target, source, pose, max_distance)
    inliers = found & (np.abs(r) < inlier_distance)
    count = int(inliers.sum())
    residual = float(np.sqrt(np.mean(r[inliers] ** 2))) if count else float("inf")
    covariance = None
    if count > 3:
        jac = _jacobian(n[inliers], moved[inliers] - pose[:2])
        sigma2 = float(np.sum(r[inliers] ** 2)) / (count - 3)
        covariance = _covariance(jac, sigma2)
    return Refinement(
        estimate=pose,
        iterations=iterations,
        converged=converged,
        inlier_ratio=count / max(len(source), 1),
        residual=residual,
        covariance=covariance,
        paired_ratio=int(found.sum()) / max(len(source), 1),
    )


def _covariance(jac: NDArray[np.float64], sigma2: float) -> NDArray[np.float64] | None:
    """σ² (JᵀJ)⁻¹, kept positive semi-definite.

    Along a corridor JᵀJ is near singular and a plain inverse can come out with negative
    variances from rounding; inverting through the eigenvalues gives the weak direction a
    huge but positive variance instead.
    """
    info = jac.T @ jac
    if not np.all(np.isfinite(info)):
        return None
    values, vectors = np.linalg.eigh(info)
    if values[-1] <= 0.0 or values[0] <= values[-1] * 1e-15:
        return None  # singular: no covariance, as the matcher has always said
    return np.asarray(sigma2 * (vectors / values) @ vectors.T, dtype=np.float64)


def refine_with(
    target: Target,
    source: NDArray[np.float64],
    guess: NDArray[np.float64],
    config: MatchConfig,
    iterate: bool = True,
) -> Refinement:
    """``refine`` with a matcher's settings; ``iterate=False`` only judges ``guess`` (its
    inliers, residual and covariance), as the figures of a match are computed."""
    return refine(
        target,
        source,
        guess,
        max_iterations=config.refine_iterations if iterate else 0,
        max_distance=config.refine_distance,
        inlier_distance=config.inlier_distance,
        degeneracy=config.degeneracy,
    )
