"""The surfaces drawn into the correlative grid between a scan's neighbouring end points."""

from __future__ import annotations

import math

import numpy as np

from vgm_studio.datasets.mount import LaserMount
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.submap import PEAK, Submap
from vgm_studio.matching.surface import stretch_points
from vgm_studio.simulation.raycast import beam_angles, cast

SPACING = 0.025


def _scan(walls: list[tuple[float, float, float, float]], mount: LaserMount | None = None) -> Scan:
    """A 181-beam, 180° scan from the origin facing +x, ray cast on ``walls``."""
    amin, inc = beam_angles(181, 180.0)
    ranges = cast((0.0, 0.0), amin + inc * np.arange(181), np.array(walls), 30.0)
    return Scan(0, 0.0, ranges.astype(np.float32), amin, inc, 30.0, mount=mount)


def _near(points: np.ndarray, xy: tuple[float, float], radius: float) -> bool:
    return bool((np.hypot(points[:, 0] - xy[0], points[:, 1] - xy[1]) < radius).any())


def test_a_wall_is_drawn_whole_up_to_where_it_is_seen_grazing():
    # A wall 1 m to the left: seen at more than 10° from grazing up to 1/tan(10°) ≈ 5.7 m ahead.
    scan = _scan([(-1.0, 1.0, 40.0, 1.0)])
    drawn = stretch_points(scan, 30.0, SPACING)
    assert np.allclose(drawn[:, 1], 1.0, atol=1e-6)
    assert 5.0 < drawn[:, 0].max() < 7.0
    # With the end points, nothing on the wall up to 5 m ahead is further than the spacing.
    ahead = np.sort(np.concatenate([scan.points(), drawn])[:, 0])
    assert np.diff(ahead[(ahead > 0.2) & (ahead < 5.0)]).max() <= SPACING + 1e-9
    # Far along it, where it is seen grazing, the end points stay apart.
    assert not _near(drawn, (10.0, 1.0), 0.5)


def test_the_gap_between_a_near_edge_and_the_wall_behind_stays_open():
    # A box whose right edge hides a wall 4 m further on.
    scan = _scan([(2.0, -0.5, 2.0, 0.5), (6.0, -10.0, 6.0, 10.0)])
    drawn = stretch_points(scan, 30.0, SPACING)
    assert _near(drawn, (2.0, 0.0), 0.05)  # the box's face is drawn
    assert _near(drawn, (6.0, 4.0), 0.05)  # and the wall's
    between = (drawn[:, 0] > 2.2) & (drawn[:, 0] < 5.8)
    assert not between.any()


def test_no_stretch_reaches_a_reading_beyond_the_range_kept():
    scan = _scan([(3.0, -20.0, 3.0, 20.0)])
    drawn = stretch_points(scan, 5.0, SPACING)
    assert len(drawn) > 0
    assert np.hypot(drawn[:, 0], drawn[:, 1]).max() <= 5.0


def test_stretches_are_placed_by_the_mount_like_the_end_points():
    walls = [(2.0, -3.0, 2.0, 3.0)]
    mount = LaserMount(0.4, -0.1, math.radians(30.0), flipped=True)
    plain, mounted = _scan(walls), _scan(walls, mount)
    assert np.allclose(
        stretch_points(mounted, 30.0, SPACING), mount.place(stretch_points(plain, 30.0, SPACING))
    )


def test_a_wall_scores_between_its_end_points_as_it_does_on_them():
    # A wall at 45°, 6 m off: neighbouring end points ~0.15 m apart, three cells.
    scan = _scan([(6.0 * math.sqrt(2) - 10.0, 10.0, 6.0 * math.sqrt(2) + 10.0, -10.0)])
    pts = scan.points()
    with_stretches = Submap.from_scans([scan], np.zeros((1, 3)), surfaces=True)
    ends_only = Submap.from_points(pts)
    mids = (pts[:-1] + pts[1:]) / 2
    mids = mids[np.hypot(*(pts[1:] - pts[:-1]).T) > 0.1]
    assert len(mids) > 10

    def values(sub: Submap) -> np.ndarray:
        i, j = sub.cells(mids)
        return sub.levels[0][i, j].astype(float) / PEAK

    assert values(with_stretches).min() > 0.6
    assert values(ends_only).mean() < 0.6


def test_no_returns_are_never_joined(recwarn):
    # A wall 2 m round the sensor, with beams that saw nothing (inf, NaN, 0) among them.
    ranges = np.full(181, 2.0, np.float32)
    ranges[10:20], ranges[30], ranges[40:45] = np.inf, np.nan, 0.0
    amin, inc = beam_angles(181, 180.0)
    scan = Scan(0, 0.0, ranges, amin, inc, 30.0)
    drawn = stretch_points(scan, 30.0, SPACING)
    assert len(drawn) > 100
    assert np.allclose(np.hypot(drawn[:, 0], drawn[:, 1]), 2.0, atol=1e-3)
    # Nothing drawn across the gaps the no-returns leave.
    angles = np.arctan2(drawn[:, 1], drawn[:, 0])
    for lo, hi in ((10, 19), (30, 30), (40, 44)):
        assert not ((angles > amin + (lo - 0.5) * inc) & (angles < amin + (hi + 0.5) * inc)).any()
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
