"""Occupancy grids: rays clear what they cross and mark where they end; pictures and limits."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from vgm_studio.errors import InputError
from vgm_studio.maps.config import MapConfig
from vgm_studio.maps.occupancy import build_map
from vgm_studio.maps.png import picture, side_by_side


def wall_scan(distance: float = 3.0, beams: int = 61) -> np.ndarray:
    """A straight wall at x = distance seen over ±30°."""
    angle = np.linspace(-math.pi / 6, math.pi / 6, beams)
    r = distance / np.cos(angle)
    return np.column_stack([r * np.cos(angle), r * np.sin(angle)])


def cell(grid, x: float, y: float) -> float:
    j = int((x - grid.origin[0]) / grid.resolution)
    i = int((y - grid.origin[1]) / grid.resolution)
    return float(grid.log_odds[i, j])


def test_a_wall_is_occupied_the_space_before_it_free_and_behind_it_unknown():
    config = MapConfig()
    grid = build_map(np.array([[0.0, 0.0, 0.0]]), [wall_scan()], config)
    assert cell(grid, 3.01, 0.0) == pytest.approx(config.log_odds_hit)
    assert cell(grid, 1.5, 0.0) == pytest.approx(config.log_odds_miss)
    assert cell(grid, 1.5, 0.5) == pytest.approx(config.log_odds_miss)
    assert cell(grid, 3.6, 0.0) == 0.0
    img = picture(grid)
    assert img.dtype == np.uint8 and img.shape == grid.shape
    # +y up in the picture: the top row is the grid's last.
    assert np.array_equal(img[0], grid.image()[-1])


def test_the_same_scan_from_two_poses_agrees_and_log_odds_are_clamped():
    config = MapConfig(clamp=1.0)
    poses = np.array([[0.0, 0.0, 0.0]] * 5 + [[1.0, 0.0, 0.0]] * 5)
    scans = [wall_scan(3.0)] * 5 + [wall_scan(2.0)] * 5
    grid = build_map(poses, scans, config)
    assert cell(grid, 3.01, 0.0) == pytest.approx(1.0)
    assert grid.log_odds.min() >= -1.0
    assert grid.known_cells() > 1000


def test_a_map_of_a_thousand_scans_is_vectorised():
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(-5, 5, (1000, 2)), rng.uniform(-3, 3, 1000)])
    angle = np.linspace(-math.pi / 2, math.pi / 2, 180)
    scans = [
        np.column_stack([r * np.cos(angle), r * np.sin(angle)])
        for r in rng.uniform(1, 8, (1000, 180))
    ]
    start = time.perf_counter()
    grid = build_map(poses, scans, MapConfig())
    # ~1 ms a scan here; a per-cell Python loop would take minutes.
    assert time.perf_counter() - start < 10.0
    assert grid.known_cells() > 50_000


def test_a_large_building_is_drawn_with_coarser_cells_that_fit():
    poses = np.array([[0.0, 0.0, 0.0], [500.0, 0.0, 0.0]])
    grid = build_map(poses, [wall_scan(), wall_scan()], MapConfig())
    assert max(grid.shape) <= MapConfig().max_cells
    assert grid.resolution > MapConfig().resolution
    # Both walls are still in it, 500 m apart.
    assert grid.known_cells() > 0
    assert grid.shape[1] * grid.resolution > 500.0


def test_a_scattered_trajectory_is_refused_with_a_clear_message():
    poses = np.array([[0.0, 0.0, 0.0], [5000.0, 0.0, 0.0]])
    with pytest.raises(InputError, match="the trajectory is broken"):
        build_map(poses, [wall_scan(), wall_scan()], MapConfig())


def test_side_by_side_puts_every_map_in_one_picture():
    a = build_map(np.zeros((1, 3)), [wall_scan(3.0)], MapConfig())
    b = build_map(np.zeros((1, 3)), [wall_scan(5.0)], MapConfig())
    both = side_by_side([a, b], ["three", "five"])
    assert both.shape[0] > max(a.shape[0], b.shape[0])
    assert both.shape[1] > a.shape[1] + b.shape[1]
