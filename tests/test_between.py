"""Scans between keyframes placed by refinements onto the keyframes around them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.graph.metrics import relation_errors
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam import between_stream
from vgm_studio.slam.between import ANCHOR_DISTANCE, BetweenPlacements, place_between
from vgm_studio.slam.between_stream import BetweenStream
from vgm_studio.slam.config import SlamConfig, ValidationConfig
from vgm_studio.slam.pipeline import MIN_POINTS, run_slam
from vgm_studio.slam.scoring import relations_from_reference


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("world")
    log = open_log(simulate(SimConfig(preset="demo", seed=4, num_beams=181), Path(folder)))
    config = SlamConfig(validation=ValidationConfig(validator="reference"))
    return log, run_slam(log, config, progress=False)


def test_refined_scans_between_keyframes_lie_nearer_the_truth_than_the_odometry_carries_them(
    run,
):
    log, result = run
    relations = relations_from_reference(log)
    assert relations is not None
    carried = relation_errors(result.scan_poses(result.after.poses, refined=False), relations)
    refined = relation_errors(result.scan_poses(result.after.poses), relations)
    assert refined.trans_mean < 0.9 * carried.trans_mean
    assert refined.rot_mean_deg < carried.rot_mean_deg


def test_anchors_lie_between_keyframes_a_step_of_odometry_apart_and_keyframes_stay(run):
    _, result = run
    between = result.between
    assert between is not None and len(between.index) > 50
    keyframes = set(result.keyframes.tolist())
    assert not keyframes & set(between.index.tolist())
    steps = np.diff(result.odometry[between.index, :2], axis=0)
    assert np.median(np.hypot(steps[:, 0], steps[:, 1])) >= 0.9 * ANCHOR_DISTANCE
    # Most anchors hold on both sides in a simulated world with walls in view.
    held = np.isfinite(between.pose_before[:, 0]) & np.isfinite(between.pose_after[:, 0])
    assert held.mean() > 0.8
    poses = result.scan_poses(result.after.poses)
    np.testing.assert_allclose(poses[result.keyframes], result.after.poses, atol=1e-12)


def test_an_anchor_that_holds_on_one_side_is_placed_by_it_and_one_that_holds_on_none_is_not():
    keyframes = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    nan = np.full(3, np.nan)
    placements = BetweenPlacements(
        index=np.array([3, 5, 7]),
        before=np.array([0, 0, 0]),
        pose_before=np.array([[0.2, 0.0, 0.0], nan, nan]),
        pose_after=np.array([[-0.8, 0.0, 0.0], [-0.4, 0.1, 0.0], nan]),
        share=np.array([0.2, 0.6, 0.8]),
    )
    index, poses = placements.place(keyframes)
    assert index.tolist() == [3, 5]
    np.testing.assert_allclose(poses[0], [0.2, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(poses[1], se2.compose(keyframes[1], [-0.4, 0.1, 0.0]))


def _stream(log, result) -> BetweenStream:
    fe = SlamConfig().front_end
    usable = np.array([len(s.points()) >= MIN_POINTS for s in log.scans])
    stream = BetweenStream(log.scans, usable, (fe.keyframe_distance, fe.keyframe_angle_deg))
    for i, pose in enumerate(result.odometry):
        stream.pose(i, pose)
    return stream


def test_anchors_refined_while_the_odometry_runs_are_those_refined_after_it(run, monkeypatch):
    log, result = run
    here = place_between(log.scans, result.odometry, result.keyframes, progress=False)

    def refused(*args, **kwargs):
        raise AssertionError("the worker's placements were not used")

    monkeypatch.setattr(between_stream, "place_between", refused)
    there = _stream(log, result).result(result.odometry, result.keyframes, progress=False)
    np.testing.assert_array_equal(there.index, here.index)
    np.testing.assert_array_equal(there.before, here.before)
    np.testing.assert_array_equal(there.pose_before, here.pose_before)
    np.testing.assert_array_equal(there.pose_after, here.pose_after)
    np.testing.assert_array_equal(there.share, here.share)


def test_keyframes_the_worker_did_not_pick_are_placed_after_the_odometry(run, monkeypatch):
    log, result = run
    made = []
    real = between_stream.place_between

    def counted(*args, **kwargs):
        made.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(between_stream, "place_between", counted)
    other = result.keyframes[::2]
    placed = _stream(log, result).result(result.odometry, other, progress=False)
    assert made == [1]
    assert not set(placed.index.tolist()) & set(other.tolist())


def test_the_worker_goes_with_a_parent_killed_outright_while_it_starts(tmp_path):
    """The worker starts without holding its parent up (the scans follow through its queue),
    so the parent can be killed before the worker has read them: it must not wait for them
    for ever."""
    from orphans import assert_worker_goes_with_its_parent, stream_parent

    log = simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=0.3), tmp_path)
    parent = stream_parent("vgm_studio.slam.between_stream", "BetweenStream")
    assert_worker_goes_with_its_parent(parent, log)


_DEAD_WORKER = """
import sys
import numpy as np
from vgm_studio.datasets import open_log
from vgm_studio.slam.between_stream import BetweenStream

log = open_log(sys.argv[1])
stream = BetweenStream(log.scans, np.ones(len(log), dtype=bool), (0.5, 20.0))
stream._proc.kill()  # dies before it has read the scans
stream._proc.join()
odometry = np.array([s.odometry for s in log.scans])
placed = stream.result(odometry, np.arange(0, len(log), 10), progress=False)
print(len(log), len(placed.index), flush=True)
"""


def test_a_worker_that_died_before_reading_its_scans_holds_nothing_up(tmp_path):
    """The scans wait in the worker's queue; a worker that died (killed, out of memory) never
    reads them. The run places the anchors itself and the process still exits, rather
    than waiting at its exit to write scans nobody reads."""
    import subprocess
    import sys

    log = simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=0.3), tmp_path)
    done = subprocess.run(
        [sys.executable, "-c", _DEAD_WORKER, str(log)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    scans, anchors = map(int, done.stdout.split())
    assert scans * 181 * 8 > 1 << 16  # more than a pipe holds
    assert anchors > 0
