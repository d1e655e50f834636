"""What the studio draws and the orders it shows edges in, without a browser."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from vgm_studio.matching.edge_scans import EdgeScans
from vgm_studio.matching.edges import read_edges
from vgm_studio.studio.queues import Queue, Snapshot, human_label, order
from vgm_studio.studio.view import make_view, pose_marks
from vgm_studio.vgm.grid import VGMParams
from vgm_studio.vgm.render import BACKGROUND


def test_heatmap_crop_lies_under_the_scan_points(office_edges):
    params = VGMParams()
    edge = next(e for e in read_edges(office_edges) if e.kind == "loop")
    view = make_view(edge, EdgeScans(), params)
    for placed, points in ((view.estimate, view.prev), (view.estimate, view.estimate.cur)):
        h, w = placed.heatmap_rgb.shape[:2]
        width, height = placed.heatmap_size
        assert np.isclose(width, w * params.resolution) and np.isclose(
            height, h * params.resolution
        )
        cx, cy = placed.heatmap_centre
        # Row i of the image runs along +y (viser puts row 0 at the image's -y edge).
        cols = np.floor((points[:, 0] - cx) / params.resolution + w / 2).astype(int)
        rows = np.floor((points[:, 1] - cy) / params.resolution + h / 2).astype(int)
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        assert inside.mean() > 0.8  # points beyond the 20 m grid are not in the VGM
        lit = placed.heatmap_rgb[rows[inside], cols[inside]].max(axis=1) > BACKGROUND + 10
        assert lit.mean() > 0.99
    # The crop is much smaller than the whole 20 m grid: that is what keeps clicks fast.
    assert view.estimate.heatmap_rgb.shape[0] * view.estimate.heatmap_rgb.shape[1] < 0.5 * 400**2


def test_pose_marks_point_along_the_heading():
    segments, colours = pose_marks(np.array([1.0, 2.0, np.pi / 2]), None)
    assert segments.shape == (4, 2, 3) and colours.shape == (4, 2, 3)
    heading = segments[2]  # the current pose's x axis
    np.testing.assert_allclose(heading[0, :2], [1.0, 2.0], atol=1e-6)
    np.testing.assert_allclose(heading[1, :2], [1.0, 2.6], atol=1e-6)
    with_reference, _ = pose_marks(np.zeros(3), (np.array([0.5, 0.0, 0.0]), np.zeros((0, 3))))
    assert with_reference.shape == (6, 2, 3)


def test_queues_order_edges_as_named():
    ids = ["a", "b", "c", "d", "e"]
    snap = Snapshot(
        ids,
        labels={
            "b": {"ana": "success"},
            "d": {"ana": "failure", "ben": "success"},
            "e": {"ana": "failure"},
        },
        predictions={"a": 0.9, "b": 0.2, "c": 0.55, "d": 0.5, "e": 0.95},
        threshold=0.5,
    )
    assert order(Queue.log, snap) == ids
    assert order(Queue.unlabelled, snap) == ["a", "c", "b", "d", "e"]
    assert order(Queue.uncertain, snap) == ["c", "a", "b", "d", "e"]
    assert order(Queue.conflicts, snap) == ["d"]
    # b: model says failure, label success; e: model success, label failure (more confident).
    assert order(Queue.disagree, snap) == ["e", "b"]
    assert order(Queue.uncertain, Snapshot(ids, labels=snap.labels)) == ["a", "c", "b", "d", "e"]
    assert human_label({"ana": "success", "ben": "failure"}) is None
    assert human_label({"ana": "success", "ben": "failure", "cy": "failure"}) == "failure"


def test_the_trainer_line_names_the_model_shown_and_why_a_version_waits():
    from vgm_studio.studio.panel import trainer_text
    from vgm_studio.trainer import TrainerStatus

    why = "v1: held-out accuracy 1.000 on 3 edges; not promoted, …: held-out set too small"
    status = TrainerStatus(
        state="idle",
        epoch=0,
        epochs=0,
        metrics={},
        labels_since=4,
        active_version=None,
        updated_at=None,
        message=why,
        pending_request=False,
        active_model="vgmnet-default.pt:0123456789ab",
    )
    text = trainer_text(status)
    assert "model vgmnet-default.pt" in text and "none yet" not in text
    assert why in text and "4 labels since" in text
    assert "none yet" in trainer_text(replace(status, active_model=None))
