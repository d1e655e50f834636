"""The studio's pictures and team figures, without a browser: heatmap, minimap, agreement."""

from __future__ import annotations

import dataclasses
import random

import numpy as np

from vgm_studio.datasets import open_log
from vgm_studio.labels.agreement import agreement, cohen_kappa
from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import read_edges
from vgm_studio.studio.heatmap import BACKGROUND_RGB, CUR_HUE, PREV_HUE, blend, channels_panel
from vgm_studio.studio.minimap import trajectory
from vgm_studio.studio.scene import framing
from vgm_studio.studio.view import CUR_RGB, PREV_RGB, make_view
from vgm_studio.vgm.grid import VGMParams


def _hue(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(float) / max(float(rgb.max()), 1.0)


def test_blend_tells_the_channels_and_their_overlap_apart():
    vgm = np.zeros((2, 3, 3), np.float32)
    vgm[0, 0, 0] = 1.0  # previous only
    vgm[1, 1, 1] = 1.0  # current only
    vgm[:, 2, 2] = 1.0  # both
    vgm[0, 0, 2] = 0.001  # a faint cell is still drawn (the floor)
    rgb = blend(vgm)
    np.testing.assert_allclose(_hue(rgb[0, 0]), PREV_HUE, atol=0.02)
    np.testing.assert_allclose(_hue(rgb[1, 1]), CUR_HUE, atol=0.02)
    assert rgb[2, 2].min() > 240  # white where both agree
    assert rgb[0, 2].max() > 60 and rgb[0, 2, 1] > rgb[0, 2, 0]
    np.testing.assert_array_equal(rgb[1, 0], BACKGROUND_RGB.astype(np.uint8))


def test_channels_panel_keeps_a_single_cell_of_a_large_crop():
    vgm = np.zeros((2, 400, 400), np.float32)
    vgm[1, 123, 321] = 0.05  # one weak hit: averaging down would fade it to nothing
    vgm[0, 5:395, 200] = 1.0
    panel = channels_panel(vgm)
    assert panel.shape[1] == 360
    right = panel[16:186, 190:]  # the current channel's tile
    assert (np.abs(right.astype(int) - BACKGROUND_RGB).max(axis=2) > 40).sum() >= 1


def test_minimap_marks_both_poses_where_the_trajectory_has_them(office_edges):
    edge = next(e for e in read_edges(office_edges) if e.kind == "loop")
    log = open_log(edge.log_path)
    path = trajectory(log)
    assert path is not None and len(path.poses) == len(log)
    view = make_view(edge, EdgeScans(), VGMParams(), path)
    assert view.minimap is not None
    u, v = path.pixel(*path.poses[edge.a][:2])
    np.testing.assert_array_equal(view.minimap[v, u], PREV_RGB)  # drawn last, on top
    u, v = path.pixel(*path.poses[edge.b][:2])
    near = view.minimap[max(v - 6, 0) : v + 7, max(u - 6, 0) : u + 7].reshape(-1, 3)
    assert (near == np.array(CUR_RGB, np.uint8)).all(axis=1).any()
    # The path itself is drawn, away from the marks too.
    assert (view.minimap != path.base).any() and (path.base != path.base[0, 0]).any()


def test_framing_fits_the_pair_and_scales_with_the_view(office_edges):
    edge = next(e for e in read_edges(office_edges) if e.kind == "loop")
    view = make_view(edge, EdgeScans(), VGMParams())
    fov = np.radians(75.0)
    wide = framing(view, view.estimate, (fov, 2.0, 800))
    narrow = framing(view, view.estimate, (fov, 1.0, 800))
    assert narrow.height >= wide.height  # a narrower view must back off (or stay)
    points = np.concatenate([view.prev[:, :2], view.estimate.cur[:, :2]])
    points = points[np.all(np.abs(points) <= view.extent / 2, axis=1)]
    for f, aspect in ((wide, 2.0), (narrow, 1.0)):
        half_h = f.height * np.tan(fov / 2)
        assert np.all(np.abs(points[:, 1] - f.y) <= half_h)
        assert np.all(np.abs(points[:, 0] - f.x) <= half_h * aspect)


def test_kappa_is_one_for_agreement_zero_for_chance_and_negative_for_opposition():
    labels = ["success", "failure"]
    rng = random.Random(0)
    same = [(x, x) for x in rng.choices(labels, k=200)]
    assert cohen_kappa(same) == 1.0
    chance = [(rng.choice(labels), rng.choice(labels)) for _ in range(4000)]
    assert abs(cohen_kappa(chance) or 0.0) < 0.05
    flip = {"success": "failure", "failure": "success"}
    assert (cohen_kappa([(x, flip[x]) for x, _ in same]) or 0.0) < -0.9
    assert cohen_kappa([("success", "success")] * 5) is None  # one label only: undefined
    assert cohen_kappa([]) is None


def test_agreement_pairs_every_two_annotators_on_their_shared_edges():
    labels = {
        "e1": {"ana": "success", "bob": "success", "cy": "failure"},
        "e2": {"ana": "failure", "bob": "success"},
        "e3": {"bob": "failure"},
    }
    pairs = {(p.first, p.second): p for p in agreement(labels)}
    assert set(pairs) == {("ana", "bob"), ("ana", "cy"), ("bob", "cy")}
    assert (pairs["ana", "bob"].shared, pairs["ana", "bob"].agreed) == (2, 1)
    assert (pairs["ana", "cy"].shared, pairs["ana", "cy"].agreed) == (1, 0)
    assert agreement(labels)[0].shared == 2  # most shared first


def _one_hued(rgb: np.ndarray) -> np.ndarray:
    """Which colours read as one channel alone: green or magenta, not white or grey."""
    c = rgb.astype(int)
    r, g, b = c[..., 0], c[..., 1], c[..., 2]
    return ((g > r + 60) & (g > b + 60)) | ((r > g + 60) & (b > g + 60))


def test_spread_makes_two_sparse_scans_of_one_wall_agree():
    from vgm_studio.vgm.spread import spread_pair

    # One wall 8 m away, each scan's returns 20 cm apart, the second's shifted by 10 cm along
    # it: a perfect match whose raw cells never coincide.
    xs = np.arange(-3.0, 3.0, 0.2)
    prev = np.column_stack([xs, np.full_like(xs, 8.02)])
    cur = prev + np.array([0.1, 0.0])
    vgm = np.zeros((2, 400, 400), np.float32)
    for k, pts in enumerate((prev, cur)):
        idx = np.floor((pts + 10.0) / 0.05).astype(int)
        vgm[k, idx[:, 1], idx[:, 0]] = 1.0
    occupied = (vgm[0] > 0) | (vgm[1] > 0)
    raw = blend(vgm)[occupied]
    assert _one_hued(raw).all()  # every cell green or magenta: reads as a failure
    spread = blend(vgm, spread_pair(vgm, (-10.0, -10.0), 0.05, (prev, cur)))[occupied]
    assert not _one_hued(spread).any() and spread.min() > 200  # white: they agree
    # Moved 40 cm off the wall (a wrong match), the two stay apart.
    wrong = np.zeros_like(vgm)
    wrong[0] = vgm[0]
    off = cur + np.array([0.0, 0.4])
    idx = np.floor((off + 10.0) / 0.05).astype(int)
    wrong[1, idx[:, 1], idx[:, 0]] = 1.0
    spread = spread_pair(wrong, (-10.0, -10.0), 0.05, (prev, off))
    occupied = (wrong[0] > 0) | (wrong[1] > 0)
    assert _one_hued(blend(wrong, spread)[occupied]).all()


def test_the_default_heatmap_reads_a_right_edge_as_agreement(office_edges):
    edges = read_edges(office_edges)
    right = next(e for e in edges if e.kind == "sequential" and e.label == "success")
    placed = make_view(right, EdgeScans(), VGMParams()).estimate
    raw, spread = _one_hued(placed.raw_rgb).mean(), _one_hued(placed.cell_rgb).mean()
    # Raw, most cells read as one scan's (0.82); spread, only the wall behind the current
    # scan, which it cannot see (0.24).
    assert raw > 0.6 and spread < raw / 2.5, (raw, spread)
    # The same pair placed 60 cm off: most cells keep one scan's hue.
    wrong = dataclasses.replace(right, estimate=[right.estimate[0], right.estimate[1] + 0.6, 0.0])
    placed = make_view(wrong, EdgeScans(), VGMParams()).estimate
    assert _one_hued(placed.cell_rgb).mean() > 0.4


def test_vgm_pictures_show_the_cells_beside_the_points(office_edges, tmp_path):
    """``vgm-studio vgm``: the VGM's cells, in their own hues, outnumber the points' pixels."""
    from vgm_studio.vgm.picture import edge_picture
    from vgm_studio.vgm.render import BACKGROUND, CUR_BGR, PREV_BGR

    edge = next(e for e in read_edges(office_edges) if e.kind == "sequential")
    bgr = edge_picture(edge, tmp_path / "e.png").astype(int)
    picture = bgr[bgr.shape[0] // 4 :]  # below the caption
    points = sum(
        int((np.abs(picture - colour.astype(int)).sum(axis=2) < 30).sum())
        for colour in (PREV_BGR, CUR_BGR)
    )
    rgb = picture[..., ::-1]
    lit = np.abs(picture - BACKGROUND).max(axis=2) > 40
    agreeing = lit & (np.ptp(rgb, axis=2) < 60)  # white or grey cells: both scans
    assert agreeing.sum() > 3 * points, (int(agreeing.sum()), points)
    assert _one_hued(rgb[lit]).sum() > 100  # and cells one scan alone has, green or magenta
