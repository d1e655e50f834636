"""SE(2) functions against matrix products."""

from __future__ import annotations

import numpy as np

from vgm_studio.core import se2


def test_compose_between_inverse_agree_with_matrices():
    rng = np.random.default_rng(3)
    for _ in range(50):
        a = np.r_[rng.normal(size=2) * 5, rng.uniform(-np.pi, np.pi)]
        b = np.r_[rng.normal(size=2) * 5, rng.uniform(-np.pi, np.pi)]
        want = se2.from_matrix(se2.to_matrix(a) @ se2.to_matrix(b))
        np.testing.assert_allclose(se2.compose(a, b), want, atol=1e-12)
        rel = se2.between(a, b)
        np.testing.assert_allclose(se2.compose(a, rel), b, atol=1e-9)
        np.testing.assert_allclose(se2.compose(a, se2.inverse(a)), 0, atol=1e-12)


def test_wrap_and_error():
    np.testing.assert_allclose(se2.wrap_angle([3 * np.pi, -np.pi, 0.5]), [np.pi, np.pi, 0.5])
    exy, eth = se2.pose_error([1, 0, 0], [1.3, 0.4, 0.1])
    assert np.isclose(exy, 0.5) and np.isclose(eth, 0.1)


def test_transform_points():
    pts = se2.transform_points([1, 2, np.pi / 2], [[1, 0], [0, 1]])
    np.testing.assert_allclose(pts, [[1, 3], [0, 2]], atol=1e-12)


def test_one_pose_gives_the_bits_a_stack_gives():
    """Single poses take a float path (10x faster); it must not move a result by a bit, or
    SLAM runs would differ with how their poses happen to be batched."""
    rng = np.random.default_rng(7)
    a = np.c_[rng.normal(size=(2000, 2)) * 20, rng.uniform(-50, 50, 2000)]
    b = np.c_[rng.normal(size=(2000, 2)) * 20, rng.uniform(-50, 50, 2000)]
    a[:4, 2] = [np.pi, -np.pi, 3 * np.pi, 0.0]
    one = np.array([se2.compose(x, y) for x, y in zip(a, b, strict=True)])
    assert np.array_equal(one, se2.compose(a, b))
    assert np.array_equal(np.array([se2.inverse(x) for x in a]), se2.inverse(a))
    assert np.array_equal(
        se2.compose([1, 2, 0.5], [3, 4, 0.25]), se2.compose([[1, 2, 0.5]], [[3, 4, 0.25]])[0]
    )
    # A heading that is not finite is no number to turn by: NaN, as for a stack.
    with np.errstate(invalid="ignore"):
        assert np.isnan(se2.compose([0, 0, np.inf], [1, 0, 0])).all()


def test_covariance_in_own_frame_is_what_gtsam_measures():
    # A matcher's spread of (x, y, θ) in the target's frame, sampled and moved into gtsam's
    # local coordinates of the measured pose, must have the covariance the function says.
    import gtsam

    rng = np.random.default_rng(5)
    z = np.array([2.0, -1.0, 1.2])
    searched = np.array([[4e-4, 5e-5, 2e-5], [5e-5, 1e-5, 0.0], [2e-5, 0.0, 1e-5]])
    deltas = rng.multivariate_normal(np.zeros(3), searched, size=20000)
    measured = gtsam.Pose2(*z)
    local = np.array([measured.localCoordinates(gtsam.Pose2(*(z + d))) for d in deltas])
    want = np.cov(local.T)
    got = se2.covariance_in_own_frame(searched, z[2])
    np.testing.assert_allclose(got, want, atol=1e-5)
    # Long along the target's x, the loop turned by 90°: long along its own y.
    turned = se2.covariance_in_own_frame(np.diag([1.0, 0.01, 0.001]), np.pi / 2)
    np.testing.assert_allclose(np.diag(turned), [0.01, 1.0, 0.001], atol=1e-12)
