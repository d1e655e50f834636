"""The loop matcher: max grids, exact branch and bound, convergence from metres off."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.matching.correlative import (
    CorrelativeConfig,
    LoopMatcher,
    SearchWindow,
    angular_step,
    branch_and_bound,
    brute_force,
)
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.submap import PEAK, Submap
from vgm_studio.simulation.simulate import SimConfig, simulate


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    path = simulate(SimConfig(preset="office", seed=3, laps=0.5), tmp_path_factory.mktemp("sim"))
    return open_log(path)


def submap_around(log, a, depth=7):
    """A submap of the keyframes around scan a, in a's frame, placed by the true poses."""
    ref = log.reference_poses()
    idx = [i for i in range(a - 6, a + 7, 3) if 0 <= i < len(log)]
    return Submap.from_scans(
        [log.scans[i] for i in idx], se2.between(ref[a], ref[idx]), depth=depth
    )


def offset(rng, metres, degrees):
    phi = rng.uniform(0, 2 * np.pi)
    sign = rng.choice([-1.0, 1.0])
    return np.array([metres * np.cos(phi), metres * np.sin(phi), sign * np.radians(degrees)])


def test_levels_hold_the_max_of_the_block_starting_at_each_cell():
    rng = np.random.default_rng(0)
    # Every cell of every level, the blocks running past the far edges read as zeros: the
    # levels are computed only where a block reaches the points' cells.
    for points, depth in ((rng.uniform(0, 3, size=(60, 2)), 4), (rng.normal(size=(9, 2)), 6)):
        sub = Submap.from_points(points, 0.05, depth=depth)
        base = sub.levels[0]
        assert base.max() == PEAK
        nx, ny = base.shape
        for h in range(1, depth + 1):
            size = 2**h
            wide = np.zeros((nx + size, ny + size), np.uint8)
            wide[:nx, :ny] = base
            blocks = np.lib.stride_tricks.sliding_window_view(wide, (size, size))
            assert np.array_equal(sub.levels[h], blocks[:nx, :ny].max(axis=(2, 3)))
        # The padding is wider than the largest block: the outermost cells are empty on all
        # levels.
        for level in sub.levels:
            assert level[0].max() == 0 and level[-1].max() == 0
            assert level[:, 0].max() == 0 and level[:, -1].max() == 0


def test_submap_from_scans_checks_its_poses(office):
    with pytest.raises(ValueError, match="2 scans but 1 poses"):
        Submap.from_scans(office.scans[:2], np.zeros((1, 3)))


def test_angular_step_moves_the_farthest_point_one_cell():
    pts = np.array([[10.0, 0.0], [1.0, 1.0]])
    step = angular_step(pts, 0.05)
    assert step == pytest.approx(0.005, rel=0.01)
    assert 10.0 * step < 0.05


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_branch_and_bound_equals_brute_force(office, seed):
    rng = np.random.default_rng(seed)
    a = int(rng.integers(10, len(office) - 30))
    b = a + int(rng.integers(3, 20))
    # A shallow submap, so a window wider than its top block starts from several blocks.
    sub = submap_around(office, a, depth=int(rng.integers(2, 5)))
    truth = se2.between(office.reference_poses()[a], office.reference_poses()[b])
    guess = truth + offset(rng, rng.uniform(0, 0.3), rng.uniform(0, 3))
    pts = office.scans[b].points()[:: int(rng.integers(1, 4))]
    window = SearchWindow(linear=0.4, angular=np.radians(3))
    step = np.radians(0.5)  # coarser than Cartographer's, to keep brute force quick
    fast = branch_and_bound(sub, pts, guess, window, step=step)
    slow = brute_force(sub, pts, guess, window, step=step)
    assert fast is not None and slow is not None
    assert fast.index == slow.index
    assert fast.score == slow.score
    np.testing.assert_allclose(fast.pose, slow.pose)
    # It is a search, not a walk: it scored fewer candidates than there are poses.
    assert fast.evaluated < slow.evaluated


def test_branch_and_bound_equals_brute_force_on_a_wrong_place(office):
    # Away from the target nothing fits well: many near-equal poses, pruning is hardest.
    sub = submap_around(office, 100, depth=3)
    pts = office.scans[500].points()[::2]
    window = SearchWindow(linear=0.5, angular=np.radians(4))
    fast = branch_and_bound(sub, pts, np.zeros(3), window, step=np.radians(1))
    slow = brute_force(sub, pts, np.zeros(3), window, step=np.radians(1))
    assert fast is not None and slow is not None
    assert (fast.index, fast.score) == (slow.index, slow.score)


def test_where_every_pose_ties_branch_and_bound_picks_brute_forces_first(office):
    # A scan far off the submap scores 0 everywhere: the tie-break alone decides.
    sub = submap_around(office, 100, depth=3)
    pts = office.scans[500].points()[::3] + 500.0
    window = SearchWindow(linear=0.3, angular=np.radians(2))
    fast = branch_and_bound(sub, pts, np.zeros(3), window, step=np.radians(1))
    slow = brute_force(sub, pts, np.zeros(3), window, step=np.radians(1))
    assert fast is not None and slow is not None
    assert (fast.index, fast.score) == (slow.index, slow.score) == ((0, 0, 0), 0.0)
    assert branch_and_bound(sub, pts, np.zeros(3), window, min_score=0.01) is None


@pytest.mark.parametrize("angular", [np.radians(5), np.pi])
def test_compiled_cells_are_numpys_to_the_last_bit(office, angular):
    from vgm_studio.matching import branch_bound

    sub = submap_around(office, 60)
    rng = np.random.default_rng(7)
    # Points near cell edges, and some far off the grid.
    points = np.concatenate([office.scans[70].points(), rng.uniform(-40, 40, (50, 2))])
    guess = np.array([0.3, -0.2, 0.1])
    w = branch_bound._discretise(sub, points, guess, SearchWindow(1.5, angular), None)
    extra = (w.stride - sub.shape[1]) // 2
    c, s = np.cos(w.angles)[:, None], np.sin(w.angles)[:, None]
    wx = guess[0] + c * points[:, 0] - s * points[:, 1]
    wy = guess[1] + s * points[:, 0] + c * points[:, 1]
    cx = np.floor((wx - sub.origin[0]) / sub.resolution).astype(np.int64)
    cy = np.floor((wy - sub.origin[1]) / sub.resolution).astype(np.int64)
    nx, ny, r = *sub.shape, w.reach
    near = (cx + r >= 0) & (cx - r < nx) & (cy + r >= 0) & (cy - r < ny)
    expected = np.where(near, (cx + extra) * w.stride + cy + extra, r * w.stride + r)
    assert (~near).any() and near.any()
    assert np.array_equal(w.base, expected)


def test_converges_from_2m_and_25deg_where_the_scan_matcher_does_not(office):
    rng = np.random.default_rng(7)
    matcher, pairwise = LoopMatcher(), ScanMatcher()
    window = SearchWindow(linear=3.0, angular=np.radians(30))
    ref = office.reference_poses()
    loop_errs, pair_errs = [], []
    for _ in range(6):
        a = int(rng.integers(10, len(office) - 40))
        b = a + int(rng.integers(8, 30))
        truth = se2.between(ref[a], ref[b])
        guess = truth + offset(rng, 2.0, 25.0)
        sub = submap_around(office, a)
        got = matcher.match(sub, office.scans[a], office.scans[b], guess, window)
        loop_errs.append(se2.pose_error(truth, got.estimate))
        old = pairwise.match(office.scans[a], office.scans[b], guess)
        pair_errs.append(se2.pose_error(truth, old.estimate))
    loop, pair = np.array(loop_errs), np.array(pair_errs)
    assert loop[:, 0].max() <= 0.03
    assert np.degrees(loop[:, 1].max()) < 1.0
    # Today's matcher, from the same guesses, stays metres off in most of them.
    assert np.sum(pair[:, 0] > 0.3) >= 4


def test_match_figures_are_those_of_the_pair(office):
    rng = np.random.default_rng(3)
    a, b = 300, 312
    ref = office.reference_poses()
    truth = se2.between(ref[a], ref[b])
    guess = truth + offset(rng, 1.0, 10.0)
    got = LoopMatcher().match(
        submap_around(office, a), office.scans[a], office.scans[b], guess, SearchWindow(2.0, 0.3)
    )
    assert got.converged and 1 <= got.iterations <= 30
    assert 0.5 < got.inlier_ratio <= 1.0
    assert 0 < got.residual < 0.03
    assert got.score is not None and 0.5 < got.score <= 1.0
    cov = np.asarray(got.covariance)
    assert cov.shape == (3, 3) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert np.sqrt(cov[0, 0]) < 0.01
    # The grid pose is within a cell or two of the truth, and the kiss_* fields say how far
    # the search moved from the guess.
    assert se2.pose_error(truth, got.kiss_estimate)[0] < 0.1
    step = se2.between(guess, got.kiss_estimate)
    assert got.kiss_moved == pytest.approx(float(np.hypot(step[0], step[1])))
    assert got.kiss_moved > 0.5
    fig = got.figures()
    assert fig["score"] == got.score and len(fig["kiss_estimate"]) == 3
    # In an office the match is pinned: its score's surface spreads by centimetres, and a
    # guess a metre off keeps little of the match's score.
    spread = np.asarray(got.spread)
    assert spread.shape == (3, 3) and np.all(np.linalg.eigvalsh(spread) >= 0)
    assert np.sqrt(spread[0, 0]) < 0.05 and np.sqrt(spread[1, 1]) < 0.05
    assert got.guess_share is not None and got.guess_share < 0.5
    # Started at the truth, the guess keeps nearly all of it.
    again = LoopMatcher().match(
        submap_around(office, a), office.scans[a], office.scans[b], truth, SearchWindow(2.0, 0.3)
    )
    assert again.guess_share is not None and again.guess_share > 0.9
    assert "spread" not in fig and "guess_share" not in fig  # the edges file's figures


def test_no_points_or_no_pose_above_min_score_returns_the_guess(office):
    sub = submap_around(office, 100)
    empty = replace(
        office.scans[0], ranges=np.full(office.scans[0].num_beams, 100.0, dtype=np.float32)
    )
    guess = np.array([0.1, 0.0, 0.0])
    window = SearchWindow(1.0, 0.2)
    got = LoopMatcher().match(sub, office.scans[100], empty, guess, window)
    np.testing.assert_allclose(got.estimate, guess)
    assert not got.converged and got.inlier_ratio == 0.0
    strict = LoopMatcher(CorrelativeConfig(min_score=0.99))
    got = strict.match(sub, office.scans[100], office.scans[700], guess, window)
    assert not got.converged and got.score is None


def test_pairwise_figures_have_no_score_key(office):
    fig = ScanMatcher().match(office.scans[10], office.scans[12], np.zeros(3)).figures()
    assert "score" not in fig and "inlier_ratio" in fig


@pytest.mark.parametrize("linear, angular", [(-1.0, 0.1), (1.0, -0.1), (1.0, 4.0)])
def test_a_window_must_be_a_window(linear, angular):
    with pytest.raises(ValueError, match="search window"):
        SearchWindow(linear, angular)


def test_the_likelihood_grid_equals_a_transform_over_the_whole_grid():
    """The distance transform runs on the points' box only: every cell must still read what a
    transform over the whole grid gives, points on the grid's edge included."""
    import cv2

    from vgm_studio.matching.submap import _likelihood

    rng = np.random.default_rng(5)
    for trial in range(60):
        shape = (int(rng.integers(8, 300)), int(rng.integers(8, 300)))
        n = int(rng.integers(1, 300))
        cells = np.stack([rng.integers(0, shape[0], n), rng.integers(0, shape[1], n)], axis=1)
        if trial % 2:  # a cluster in the middle, as a submap's points sit
            cells = cells // 9 + np.array(shape) // 3
        sigma = float(rng.choice([0.7, 1.0, 2.0]))
        free = np.full(shape, 255, dtype=np.uint8)
        free[cells[:, 0], cells[:, 1]] = 0
        dist = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_5)
        full = np.where(dist > 3.0 * sigma, 0.0, PEAK * np.exp(-0.5 * (dist / sigma) ** 2))
        grid = np.zeros(shape, dtype=np.uint8)
        (x0, y0), (x1, y1) = _likelihood(cells, shape, sigma, out=grid)
        assert np.array_equal(grid, np.rint(full).astype(np.uint8))
        # Nothing outside the box it returns scores.
        assert grid.sum() == grid[x0:x1, y0:y1].sum()


def test_a_surface_scores_every_pose_of_its_window_as_brute_force_does(office):
    """``surface`` (the score surface a match's spread is read from) sums in a compiled
    kernel; each pose must score what brute force's numpy gather gives it."""
    from vgm_studio.matching import branch_bound

    ref = office.reference_poses()
    sub = submap_around(office, 20)
    points = ScanMatcher().points(office.scans[24])
    guess = se2.between(ref[20], ref[24]) + np.array([0.03, -0.02, 0.01])
    for window in (
        SearchWindow(0.5, 0.0),
        SearchWindow(0.0, np.radians(3)),
        SearchWindow(0.2, 0.05),
    ):
        angles, shifts, scores = branch_bound.surface(sub, points, guess, window)
        w = branch_bound._discretise(sub, points, guess, window, None)
        a, x, y = np.meshgrid(
            np.arange(len(w.angles)), *(2 * [np.arange(-w.reach, w.reach + 1)]), indexing="ij"
        )
        expected = branch_bound._scores(w, 0, a.ravel(), x.ravel(), y.ravel())
        assert np.array_equal(scores.ravel(), expected)
        assert np.array_equal(angles, w.angles) and len(shifts) == 2 * w.reach + 1


def test_scores_gathered_in_chunks_equal_one_gather_of_every_candidate(office):
    from vgm_studio.matching import branch_bound

    ref = office.reference_poses()
    sub = submap_around(office, 20)
    points = ScanMatcher().points(office.scans[24])
    guess = se2.between(ref[20], ref[24])
    w = branch_bound._discretise(sub, points, guess, SearchWindow(1.0, np.radians(10)), None)
    rng = np.random.default_rng(0)
    rows = branch_bound._chunk_rows(len(points))
    count = 3 * rows + 7  # three whole chunks and a part
    a = rng.integers(0, len(w.angles), count)
    x, y = (rng.integers(-w.reach, w.reach + 1, count) for _ in range(2))
    for h in (0, 2):
        whole = np.take(w.levels[h], w.base[a] + (x * w.stride + y)[:, None]).sum(axis=1)
        assert np.array_equal(branch_bound._scores(w, h, a, x, y), whole)
    assert rows < count
