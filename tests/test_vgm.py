"""The VGM against a plain per-cell loop written from the issue's definition."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.vgm import grid_map, pair_map
from vgm_studio.vgm.grid import batch_cells, pair_maps


def plain_grid_map(points, size=400, resolution=0.05, sigma=0.02):
    """The definition, one cell at a time, with no vectorisation."""
    half = size * resolution / 2
    cells: dict[tuple[int, int], list[tuple[float, float]]] = {}
    for x, y in points:
        j = math.floor((x + half) / resolution)
        i = math.floor((y + half) / resolution)
        if 0 <= i < size and 0 <= j < size:
            cells.setdefault((i, j), []).append((x, y))
    out = np.zeros((size, size), dtype=np.float64)
    if not cells:
        return out
    n_max = max(len(v) for v in cells.values())
    for (i, j), pts in cells.items():
        p = np.array(pts)
        mu = p.mean(axis=0)
        cov = (p - mu).T @ (p - mu) / len(p) + sigma**2 * np.eye(2)
        c = np.array([-half + (j + 0.5) * resolution, -half + (i + 0.5) * resolution])
        d = c - mu
        out[i, j] = math.exp(-0.5 * d @ np.linalg.inv(cov) @ d) * len(p) / n_max
    return out


def test_random_points_match_plain_loop():
    rng = np.random.default_rng(1)
    # Clustered points so that many cells hold several points, plus some outside the grid.
    centres = rng.uniform(-9, 9, size=(40, 2))
    pts = np.concatenate([c + rng.normal(0, 0.03, size=(12, 2)) for c in centres])
    pts = np.concatenate([pts, rng.uniform(-15, 15, size=(50, 2))])
    got = grid_map(pts)
    want = plain_grid_map(pts)
    assert got.dtype == np.float32 and got.shape == (400, 400)
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert (got > 0).sum() > 100
    assert got.max() <= 1.0


@pytest.mark.parametrize(("size", "resolution", "sigma"), [(64, 0.1, 0.05), (128, 0.02, 0.01)])
def test_other_parameters_match_plain_loop(size, resolution, sigma):
    rng = np.random.default_rng(size)
    pts = rng.normal(0, size * resolution / 5, size=(500, 2))
    np.testing.assert_allclose(
        grid_map(pts, size=size, resolution=resolution, sigma=sigma),
        plain_grid_map(pts, size, resolution, sigma),
        atol=1e-5,
    )


def test_real_scans_match_plain_loop(datasets):
    log = open_log(datasets / "intel" / "intel.gfs.log")
    a, b = log.scans[100], log.scans[101]
    estimate = se2.between(a.reference, b.reference)
    got = pair_map(a.points(), b.points(), estimate)
    assert got.shape == (2, 400, 400) and got.dtype == np.float32
    np.testing.assert_allclose(got[0], plain_grid_map(a.points()), atol=1e-5)
    moved = se2.transform_points(estimate, b.points())
    np.testing.assert_allclose(got[1], plain_grid_map(moved), atol=1e-5)


def test_cell_layout_rows_run_along_y():
    # One point in the cell at x ∈ [0.05, 0.10), y ∈ [−0.10, −0.05) → j = 201, i = 198.
    g = grid_map(np.array([[0.07, -0.08]]))
    (i, j) = np.argwhere(g > 0)[0]
    assert (i, j) == (198, 201)


def test_point_at_cell_centre_scores_one_and_offsets_score_less():
    centre = np.array([[0.025, 0.025]])
    assert grid_map(centre)[200, 200] == pytest.approx(1.0)
    off = grid_map(np.array([[0.045, 0.025]]))[200, 200]
    assert off == pytest.approx(math.exp(-0.5 * 0.02**2 / 0.02**2), rel=1e-6)


def test_hit_ratio_weights_by_count():
    pts = np.array([[0.025, 0.025]] * 4 + [[1.025, 1.025]])
    g = grid_map(pts)
    assert g[200, 200] == pytest.approx(1.0)
    assert g[220, 220] == pytest.approx(0.25)


def test_empty_and_outside_points_give_zero_grid():
    assert not grid_map(np.zeros((0, 2))).any()
    assert not grid_map(np.array([[50.0, 0.0], [0.0, -10.0001]])).any()


def test_pair_map_moves_current_scan_by_estimate():
    prev = np.array([[1.025, 0.025]])
    cur = np.array([[0.025, 0.025]])
    # Translating the current scan by +1 m in x puts its point on the previous one.
    vgm = pair_map(prev, cur, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(vgm[0], vgm[1], atol=1e-6)
    rotated = pair_map(prev, np.array([[0.025, -1.025]]), [0.0, 0.0, math.pi / 2])
    np.testing.assert_allclose(rotated[1], vgm[0], atol=1e-5)


def _simulated_scans(tmp_path, count):
    from vgm_studio.simulation.simulate import SimConfig, simulate

    log = open_log(simulate(SimConfig(preset="office", seed=3, laps=0.2), tmp_path))
    return [s.points() for s in log.scans[:count]]


def test_batched_pair_maps_equal_each_pair_alone(tmp_path):
    rng = np.random.default_rng(7)
    sim = _simulated_scans(tmp_path, 4)
    # Random clouds, simulated scans, an empty scan, one lone point (a single-point cell and
    # n_max = 1) and a scan wholly outside the grid: each channel keeps its own n_max.
    prevs = [rng.normal(0, 3, (250, 2)), sim[0], np.zeros((0, 2)), sim[2], [[50.0, 0.0]]]
    curs = [sim[1], rng.normal(0, 0.05, (40, 2)), sim[3], [[0.33, -1.2]], np.zeros((0, 2))]
    estimates = [[0.1, -0.2, 0.3], [0.0, 0.0, 0.0], [1.0, 2.0, -1.0], [0.5, 0.5, 2.0], [0, 0, 1]]
    batched = pair_maps(prevs, curs, estimates)
    assert batched.shape == (5, 2, 400, 400)
    for k in range(5):
        alone = pair_map(prevs[k], curs[k], estimates[k])
        np.testing.assert_allclose(batched[k], alone, rtol=1e-6, atol=1e-7)
        want = plain_grid_map(se2.transform_points(estimates[k], np.reshape(curs[k], (-1, 2))))
        np.testing.assert_allclose(batched[k, 1], want, atol=1e-5)
    assert not batched[2, 0].any() and not batched[4].any()
    assert np.count_nonzero(batched[3, 1]) == 1 and np.count_nonzero(batched[0, 0]) > 100


def test_batch_cells_sorted_by_channel_with_empty_channels_left_out():
    channel, cell, value = batch_cells([np.zeros((0, 2)), [[0.01, 0.01]], np.zeros((0, 2))])
    assert channel.tolist() == [1] and cell.tolist() == [200 * 400 + 200]
    assert value[0] == pytest.approx(grid_map([[0.01, 0.01]])[200, 200])
    none = batch_cells([])
    assert all(len(a) == 0 for a in none)


def test_a_large_batch_built_in_parts_on_threads_equals_it_built_in_one(monkeypatch):
    """``batch_cells`` builds a batch of many points in runs of whole clouds on threads; each
    channel's cells and values are those of the batch built in one pass, to the bit."""
    from vgm_studio.vgm import grid

    rng = np.random.default_rng(3)
    clouds = [rng.normal(0.0, 3.0, (int(rng.integers(0, 1200)), 2)) for _ in range(300)]
    clouds.insert(150, np.zeros((0, 2)))
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert len(grid._parts([np.asarray(c) for c in clouds])) == 3
    parts = batch_cells(clouds)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert len(grid._parts([np.asarray(c) for c in clouds])) == 1
    whole = batch_cells(clouds)
    assert len(whole[0]) > 100_000
    for got, want in zip(parts, whole, strict=True):
        assert got.dtype == want.dtype and np.array_equal(got, want)


def numpy_cells(arrays, size, resolution, sigma):
    """The sort-and-bincount build the compiled kernel replaced, as it was."""
    pts = np.concatenate(arrays) if arrays else np.zeros((0, 2))
    owner = np.repeat(np.arange(len(arrays)), [len(a) for a in arrays])
    half = 0.5 * size * resolution
    ij = np.floor((pts + half) / resolution)
    col, row = ij[:, 0], ij[:, 1]
    inside = (col >= 0) & (col < size) & (row >= 0) & (row < size)
    pts, owner, ij = pts[inside], owner[inside], ij[inside].astype(np.int64)
    d = pts - ((ij + 0.5) * resolution - half)
    key, inv, n = np.unique(
        (owner * size + ij[:, 1]) * size + ij[:, 0], return_inverse=True, return_counts=True
    )
    channel, cell = np.divmod(key, size * size)
    dx, dy = d[:, 0], d[:, 1]
    mx, my = np.bincount(inv, dx) / n, np.bincount(inv, dy) / n
    var = sigma * sigma
    sxx = np.bincount(inv, dx * dx) / n - mx * mx + var
    syy = np.bincount(inv, dy * dy) / n - my * my + var
    sxy = np.bincount(inv, dx * dy) / n - mx * my
    mahal = (syy * mx * mx - 2.0 * sxy * mx * my + sxx * my * my) / (sxx * syy - sxy * sxy)
    n_max = np.zeros(len(arrays), dtype=np.int64)
    np.maximum.at(n_max, channel, n)
    return channel, cell, (np.exp(-0.5 * mahal) * (n / n_max[channel])).astype(np.float32)


def test_compiled_cells_equal_numpys_sort_and_bincount_to_the_bit(datasets):
    """Models were trained on VGMs built with numpy: the compiled build must give the same
    cells and values to the last bit, on real scans and on hostile clouds (NaN, inf, points
    on cell borders, off the grid, sigma 0)."""
    from vgm_studio.vgm.cell_kernel import cell_moments

    log = open_log(datasets / "intel" / "intel.gfs.log")
    real = [s.points() for s in log.scans[:400]]
    rng = np.random.default_rng(7)
    hostile = []
    for _ in range(200):
        p = rng.normal(0.0, rng.uniform(0.05, 15.0), (int(rng.integers(0, 300)), 2))
        if len(p):
            p[rng.integers(0, len(p), 3)] = rng.choice([np.nan, np.inf, -np.inf])
            p[rng.integers(0, len(p)), int(rng.integers(0, 2))] = np.nan  # one coordinate
        hostile.append(np.round(p / 0.05) * 0.05 if rng.random() < 0.3 else p)
    for clouds, size, resolution, sigma in [
        (real, 400, 0.05, 0.02),
        (hostile, 400, 0.05, 0.02),
        (hostile, 7, 1.0, 0.0),
        ([], 400, 0.05, 0.02),
    ]:
        with np.errstate(all="ignore"):
            got = cell_moments(clouds, size, resolution, sigma)
            want = numpy_cells(clouds, size, resolution, sigma)
        for g, w in zip(got, want, strict=True):
            assert g.dtype == w.dtype and np.array_equal(g, w, equal_nan=True)
    assert len(cell_moments(real, 400, 0.05, 0.02)[0]) > 50_000
