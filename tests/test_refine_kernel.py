"""The compiled refinement against the plain numpy algorithm it replaces: every nearest point
by brute force, every line normal by a full sort of distances, Gauss-Newton in arrays."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.refinement import Target, refine, refine_pose, refine_with

LEVER = 5.0


def _normals(points: NDArray[np.float64], k: int) -> NDArray[np.float64]:
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    nb = points[np.argsort(d, axis=1, kind="stable")[:, :k]]
    c = nb - nb.mean(axis=1, keepdims=True)
    sxx, syy = (c[..., 0] ** 2).sum(1), (c[..., 1] ** 2).sum(1)
    sxy = (c[..., 0] * c[..., 1]).sum(1)
    phi = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    return np.stack([-np.sin(phi), np.cos(phi)], axis=1)


def _residuals(target, normals, source, pose, gate):
    moved = se2.transform_points(pose, source)
    d = np.linalg.norm(moved[:, None] - target[None], axis=2)
    idx = d.argmin(axis=1)
    found = d[np.arange(len(moved)), idx] < gate
    n = normals[idx]
    r = np.einsum("ij,ij->i", n, moved - target[idx])
    jac = np.column_stack(
        [n[:, 0], n[:, 1], n[:, 1] * (moved[:, 0] - pose[0]) - n[:, 0] * (moved[:, 1] - pose[1])]
    )
    return r[found], jac[found], int(found.sum())


def _reference(target, source, guess, iterations=30, gate=0.3, inlier=0.05, tol=5e-4, deg=0.005):
    normals = _normals(target, 6)
    pose, it, converged = np.array(guess, dtype=np.float64), 0, False
    for it in range(1, iterations + 1):  # noqa: B007
        r, jac, paired = _residuals(target, normals, source, pose, gate)
        if paired < 3:
            break
        w = np.minimum(1.0, inlier / np.maximum(np.abs(r), 1e-12))
        scale = np.array([1.0, 1.0, 1.0 / LEVER])
        h = (jac.T @ (jac * w[:, None])) * np.outer(scale, scale)
        g = (jac.T @ (w * r)) * scale
        lam, vec = np.linalg.eigh(h)
        keep = lam > deg * lam[-1]
        delta = -(vec[:, keep] @ ((vec[:, keep].T @ g) / lam[keep])) * scale
        pose = pose + delta
        pose[2] = se2.wrap(pose[2])
        if np.linalg.norm(delta) < tol:
            converged = True
            break
    r, jac, paired = _residuals(target, normals, source, pose, gate)
    inliers = np.abs(r) < inlier
    return pose, it, converged, int(inliers.sum()), paired, jac[inliers], r[inliers]


def _room(rng: np.random.Generator) -> NDArray[np.float64]:
    """A room's walls and a pillar, sampled unevenly, as a laser sees them."""
    t = rng.uniform(0, 1, 300)
    walls = np.concatenate(
        [
            np.column_stack([-4 + 8 * t[:80], np.full(80, 3.0)]),
            np.column_stack([np.full(80, 4.0), -3 + 6 * t[80:160]]),
            np.column_stack([-4 + 6 * t[160:240], np.full(80, -3.0)]),
            np.column_stack([1.0 + 0.3 * np.cos(7 * t[240:]), 0.5 + 0.3 * np.sin(7 * t[240:])]),
        ]
    )
    return walls + rng.normal(0, 0.005, walls.shape)


@pytest.mark.parametrize("seed", range(6))
def test_refinement_finds_what_brute_force_gauss_newton_finds(seed):
    rng = np.random.default_rng(seed)
    target = _room(rng)
    truth = np.array([0.3, -0.2, 0.1])
    # The source sees the room from the truth pose, with its own noise and dropped points.
    source = se2.transform_points(se2.inverse(truth), _room(rng)[rng.uniform(size=300) < 0.8])
    guess = truth + rng.normal(0, [0.05, 0.05, 0.02])

    got = refine(Target.build(target), source, guess)
    pose, iterations, converged, inliers, paired, jac, r = _reference(target, source, guess)

    np.testing.assert_allclose(got.estimate, pose, atol=1e-9)
    assert (got.iterations, got.converged) == (iterations, converged)
    assert got.inlier_ratio == inliers / len(source)
    assert got.paired_ratio == paired / len(source)
    assert got.residual == pytest.approx(float(np.sqrt(np.mean(r**2))), rel=1e-9)
    sigma2 = float(np.sum(r**2)) / (inliers - 3)
    assert got.covariance is not None
    np.testing.assert_allclose(got.covariance, sigma2 * np.linalg.inv(jac.T @ jac), rtol=1e-6)
    # And it did its job: the room lands within millimetres of where it is.
    assert np.abs(got.estimate - truth).max() < 0.01


@pytest.mark.parametrize("seed", range(3))
def test_the_pose_alone_is_the_refinements_own(seed):
    """``refine_pose`` (a loop match settling on its submap) skips the figures, not a step."""
    rng = np.random.default_rng(seed)
    target = Target.build(_room(rng))
    truth = np.array([0.3, -0.2, 0.1])
    source = se2.transform_points(se2.inverse(truth), _room(rng))
    guess = truth + rng.normal(0, [0.05, 0.05, 0.02])
    config = MatchConfig()
    whole = refine_with(target, source, guess, config)
    pose, iterations, converged = refine_pose(target, source, guess, config)
    assert np.array_equal(pose, whole.estimate)
    assert (iterations, converged) == (whole.iterations, whole.converged)


@pytest.mark.parametrize("count", [3, 7, 40, 2000])
def test_line_normals_are_those_of_the_nearest_points_found_by_a_full_sort(count):
    rng = np.random.default_rng(count)
    # Clustered as a laser's points are: dense walls, a few stray points metres away.
    points = np.concatenate([_room(rng), rng.uniform(-30, 30, (20, 2))])[:count]
    np.testing.assert_allclose(Target.build(points).normals, _normals(points, 6), atol=1e-9)


def test_a_point_beyond_the_gate_pairs_with_nothing():
    target = np.column_stack([np.linspace(0, 2, 50), np.zeros(50)])
    # Two points 0.29 m off the wall pair; two 0.31 m off do not.
    source = np.array([[0.5, 0.29], [1.5, -0.29], [0.5, 0.31], [1.5, -0.31]])
    got = refine(Target.build(target), source, np.zeros(3), max_iterations=0, max_distance=0.3)
    assert got.paired_ratio == 0.5
    assert got.inlier_ratio == 0.0
    # Far from every point, nothing pairs at all.
    far = refine(Target.build(target), source + 100.0, np.zeros(3), max_iterations=3)
    assert far.paired_ratio == 0.0 and far.iterations == 1 and not far.converged


def test_normals_computed_as_a_refinement_meets_them_are_those_computed_up_front():
    rng = np.random.default_rng(7)
    # A submap-sized target, a scan's worth of it moved: the scan meets part of the target.
    points = np.concatenate([_room(rng) + offset for offset in [(0, 0), (9, 0), (0, 7), (9, 7)]])
    source = se2.transform_points(se2.inverse(np.array([0.04, -0.03, 0.02])), points[:300])
    lazy, eager = Target.build(points), Target.build(points)
    up_front = eager.normals  # every normal computed before any refinement
    got = refine_with(lazy, source, np.zeros(3), MatchConfig())
    want = refine_with(eager, source, np.zeros(3), MatchConfig())
    assert np.array_equal(got.estimate, want.estimate)
    assert np.array_equal(got.covariance, want.covariance)
    met = ~np.isnan(lazy._normals[:, 0])
    assert 0 < met.sum() < len(points) // 2, "the refinement computed normals it never met"
    assert np.array_equal(lazy.normals, up_front)
