"""The score surface's covariance around a match: long where the scan could slide, short where
it is pinned."""

from __future__ import annotations

import math

import numpy as np

from vgm_studio.matching.response import response_surface, score_at
from vgm_studio.matching.submap import Submap


def _walls(length: float, ends: bool) -> np.ndarray:
    """Two walls 2 m apart along x, every 2 cm; with ``ends``, a wall across each end."""
    x = np.arange(-length / 2, length / 2, 0.02)
    sides = [np.column_stack([x, np.full_like(x, y)]) for y in (-1.0, 1.0)]
    if ends:
        y = np.arange(-1.0, 1.0, 0.02)
        sides += [np.column_stack([np.full_like(y, e), y]) for e in (-length / 2, length / 2)]
    return np.concatenate(sides)


def _spread(walls: np.ndarray, seen: float) -> np.ndarray:
    """The spread of the part of ``walls`` within ``seen`` of the origin, on all of them."""
    submap = Submap.from_points(walls, 0.05)
    scan = walls[np.max(np.abs(walls), axis=1) <= seen]
    found = response_surface(submap, scan, np.zeros(3), 0.5, math.radians(3.0), 3.0)
    cov = found.covariance
    assert cov is not None
    # The surface's centre is the pose itself.
    assert found.score == score_at(submap, scan, np.zeros(3)) > 0
    return np.sqrt(np.diag(cov))


def test_a_corridor_reads_long_along_and_short_across():
    along, across, turn = _spread(_walls(8.0, ends=False), seen=2.0)
    # Nothing along the corridor tells one pose from the next: the whole ±0.5 m window
    # (a flat spread over it has σ 0.29 m).
    assert along > 0.25
    assert across < 0.03
    assert turn < math.radians(0.5)


def test_a_closed_room_pins_the_scan_both_ways():
    along, across, _ = _spread(_walls(3.0, ends=True), seen=2.0)
    assert along < 0.03 and across < 0.03


def test_a_scan_off_the_grid_has_no_spread():
    submap = Submap.from_points(_walls(3.0, ends=True), 0.05)
    far = _walls(3.0, ends=True) + 50.0
    found = response_surface(submap, far, np.zeros(3), 0.5, 0.05, 3.0)
    assert found.covariance is None and found.score == 0.0


def test_the_score_at_the_pose_is_the_surfaces_centre():
    """A match's score at its pose comes from the surface it has just sampled; it must be
    what ``score_at`` scores there, wherever the pose falls in its cell and whatever part of
    the scan is off the grid."""
    walls = _walls(3.0, ends=True)
    submap = Submap.from_points(walls, 0.05)
    rng = np.random.default_rng(3)
    for _ in range(40):
        pose = np.array([*rng.uniform(-1.6, 1.6, 2), rng.uniform(-0.3, 0.3)])
        found = response_surface(submap, walls, pose, 0.5, math.radians(3.0), 3.0)
        assert found.score == score_at(submap, walls, pose)
