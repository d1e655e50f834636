"""Scan matching on simulated pairs with known truth: accuracy, figures, degeneracy."""

from __future__ import annotations

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.simulation.simulate import SimConfig, simulate


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    path = simulate(SimConfig(preset="office", seed=3, laps=0.5), tmp_path_factory.mktemp("sim"))
    return open_log(path)


def perturbed_pairs(log, count, rng, max_xy=0.2, max_deg=5.0):
    ref = log.reference_poses()
    for _ in range(count):
        a = int(rng.integers(0, len(log) - 20))
        b = a + int(rng.integers(1, 20))
        truth = se2.between(ref[a], ref[b])
        r, phi = rng.uniform(0, max_xy), rng.uniform(0, 2 * np.pi)
        noise = [r * np.cos(phi), r * np.sin(phi), np.radians(rng.uniform(-max_deg, max_deg))]
        yield a, b, truth, truth + noise


def test_median_error_within_1cm_and_0_2deg(office):
    rng = np.random.default_rng(0)
    refined, kiss_only = ScanMatcher(), ScanMatcher(MatchConfig(refine=False))
    errs, kiss_errs = [], []
    for a, b, truth, guess in perturbed_pairs(office, 80, rng):
        errs.append(
            se2.pose_error(truth, refined.match(office.scans[a], office.scans[b], guess).estimate)
        )
        kiss_errs.append(
            se2.pose_error(truth, kiss_only.match(office.scans[a], office.scans[b], guess).estimate)
        )
    e, k = np.array(errs), np.array(kiss_errs)
    assert np.median(e[:, 0]) <= 0.01
    assert np.degrees(np.median(e[:, 1])) <= 0.2
    # The 2D refinement is there because kiss-icp alone is less precise.
    assert np.median(e[:, 0]) < np.median(k[:, 0])


def test_match_figures(office):
    rng = np.random.default_rng(1)
    a, b, _, guess = next(perturbed_pairs(office, 1, rng))
    result = ScanMatcher().match(office.scans[a], office.scans[b], guess)
    fig = result.figures()
    assert 0.5 < fig["inlier_ratio"] <= 1.0
    assert 0 < fig["residual"] < 0.03
    assert 1 <= fig["iterations"] <= 30
    cov = np.array(fig["covariance"])
    assert cov.shape == (3, 3)
    np.testing.assert_allclose(cov, cov.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert np.sqrt(cov[0, 0]) < 0.01
    assert len(fig["kiss_estimate"]) == 3


def test_far_guess_fails_and_figures_drop(office):
    # 1.5 m and 40° off: the matcher lands in the wrong place, and says so by its figures.
    rng = np.random.default_rng(2)
    a, b, truth, _ = next(perturbed_pairs(office, 1, rng))
    matcher = ScanMatcher()
    good = matcher.match(office.scans[a], office.scans[b], truth)
    bad = matcher.match(
        office.scans[a], office.scans[b], truth + np.array([1.5, -1.0, np.radians(40)])
    )
    assert se2.pose_error(truth, bad.estimate)[0] > 0.3
    assert bad.inlier_ratio < good.inlier_ratio


def test_degenerate_corridor_keeps_along_axis_from_guess(tmp_path):
    # In a featureless corridor the along-axis offset is barely observable: the refinement
    # must not wander along it (it stays near kiss-icp's value) while fixing the cross-axis.
    log = open_log(simulate(SimConfig(preset="corridor", seed=5, laps=0.3), tmp_path))
    ref = log.reference_poses()
    a, b = 40, 48
    truth = se2.between(ref[a], ref[b])
    guess = truth + np.array([0.0, 0.15, 0.0])
    result = ScanMatcher().match(log.scans[a], log.scans[b], guess)
    err = se2.between(truth, result.estimate)
    assert abs(err[1]) < 0.02
    assert abs(result.estimate[0] - result.kiss_estimate[0]) < 0.1


def test_too_few_points_returns_guess(office):
    from dataclasses import replace

    empty = replace(
        office.scans[0], ranges=np.full(office.scans[0].num_beams, 100.0, dtype=np.float32)
    )
    result = ScanMatcher().match(empty, office.scans[1], np.array([0.1, 0.0, 0.0]))
    np.testing.assert_allclose(result.estimate, [0.1, 0.0, 0.0])
    assert result.inlier_ratio == 0.0 and not result.converged


def test_kiss_moved_reports_how_far_kiss_icp_moved_the_guess(office):
    rng = np.random.default_rng(2)
    a, b, _, guess = next(perturbed_pairs(office, 1, rng, max_xy=0.2))
    fig = ScanMatcher().match(office.scans[a], office.scans[b], guess).figures()
    step = se2.between(guess, fig["kiss_estimate"])
    assert fig["kiss_moved"] == pytest.approx(float(np.hypot(step[0], step[1])))
    assert fig["kiss_turned"] == pytest.approx(abs(float(step[2])))
    # The guess was off, so kiss-icp had to move it.
    assert fig["kiss_moved"] > 0.005
    # Existing keys keep their names.
    assert {"iterations", "converged", "inlier_ratio", "residual", "covariance"} <= set(fig)


def test_covariance_of_two_parallel_walls_is_positive_and_open_along_them():
    # Two walls, parallel to a millimetre over 20 m: almost nothing fixes the position along
    # them. A plain inverse of such information can come out with negative variances.
    from vgm_studio.matching.refinement import Target, refine

    x = np.linspace(-10.0, 10.0, 400)
    walls = np.vstack(
        [np.column_stack([x, np.full_like(x, 1.0)]), np.column_stack([x, -1.0 + 5e-5 * x])]
    )
    noisy = walls + np.random.default_rng(0).normal(0.0, 0.01, walls.shape)
    result = refine(Target.build(walls, 5), noisy, np.zeros(3), max_iterations=5)
    assert result.covariance is not None
    assert np.all(np.linalg.eigvalsh(result.covariance) >= 0.0)
    # Along the walls (x) the variance dwarfs the one across them (y).
    assert result.covariance[0, 0] > 1e3 * result.covariance[1, 1]
