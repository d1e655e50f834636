"""Submap VGMs: which neighbours join a scan, and where their points land."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.test_cli_checks import one_line_error, run
from vgm_studio.core import se2
from vgm_studio.datasets import Scan
from vgm_studio.datasets.mount import LaserMount
from vgm_studio.errors import InputError
from vgm_studio.model.context import Context, LocalMapper, log_poses, neighbours, seen_by

_BEAMS = 8  # a ring of beams 45° apart, each 2 m long


def _scan(index: int, pose: tuple[float, float, float] | None, *, odometry: bool = False) -> Scan:
    ranges = np.full(_BEAMS, 2.0, np.float32)
    placed = None if pose is None else np.array(pose, dtype=np.float64)
    if odometry:
        return Scan(
            index, float(index), ranges, -math.pi, 2 * math.pi / _BEAMS, 30.0, odometry=placed
        )
    return Scan(index, float(index), ranges, -math.pi, 2 * math.pi / _BEAMS, 30.0, reference=placed)


def _line(n: int, step: float) -> list[Scan]:
    """``n`` scans driving along +x, ``step`` metres apart."""
    return [_scan(i, (i * step, 0.0, 0.0)) for i in range(n)]


def test_neighbours_are_spaced_on_both_sides_up_to_the_count():
    scans = _line(40, 0.25)
    # 0.5 m apart: every second scan, two on each side.
    assert neighbours(log_poses(scans), 20, 100, Context(neighbours=2)) == [16, 18, 22, 24]
    assert neighbours(
        log_poses(scans), 20, 100, Context(neighbours=3, spacing=0.75, reach=3.0)
    ) == [
        11,
        14,
        17,
        23,
        26,
        29,
    ]
    assert neighbours(log_poses(scans), 20, 100, Context()) == []  # the scan alone by default


def test_the_walk_stops_at_its_reach_and_at_the_log_ends():
    scans = _line(40, 0.25)
    # 0.6 m of path holds one neighbour at 0.5 m, not a second at 1.0 m.
    assert neighbours(log_poses(scans), 20, 100, Context(neighbours=2, reach=0.6)) == [18, 22]
    assert neighbours(log_poses(scans), 1, 100, Context(neighbours=2)) == [3, 5]
    # A robot standing still: no scan is ever far enough, and the walk gives up.
    still = [_scan(i, (0.0, 0.0, 0.0)) for i in range(30)]
    assert neighbours(log_poses(still), 15, 100, Context(neighbours=2, scans=10)) == []


def test_a_turn_on_the_spot_makes_a_neighbour():
    scans = [_scan(i, (0.0, 0.0, 0.2 * i)) for i in range(10)]
    assert neighbours(log_poses(scans), 0, 100, Context(neighbours=2, turn=0.35)) == [2, 4]


def test_no_neighbour_is_nearer_the_other_scan_than_its_own():
    scans = _line(40, 0.25)
    # The other scan 3 ahead: scan 22 is nearer it, so the walk ahead ends there.
    assert neighbours(log_poses(scans), 20, 23, Context(neighbours=2)) == [16, 18]
    sides = neighbours(log_poses(scans), 23, 20, Context(neighbours=2))
    assert sides == [25, 27]
    assert not set(sides) & set(neighbours(log_poses(scans), 20, 23, Context(neighbours=2)))


def test_a_scan_without_a_pose_has_no_neighbours_and_stops_the_walk():
    scans = _line(20, 0.5)
    assert (
        neighbours(
            log_poses([*scans[:10], _scan(10, None), *scans[11:]]), 10, 100, Context(neighbours=2)
        )
        == []
    )
    gap = [*scans[:12], _scan(12, None), *scans[13:]]
    assert neighbours(log_poses(gap), 10, 100, Context(neighbours=2)) == [8, 9, 11]


def test_odometry_places_the_neighbours_where_the_log_has_no_reference():
    scans = [_scan(i, (i * 0.5, 0.0, 0.0), odometry=True) for i in range(10)]
    assert neighbours(log_poses(scans), 5, 100, Context(neighbours=1)) == [4, 6]


@pytest.mark.parametrize("turn", [0.0, 1.1])
def test_neighbours_points_land_where_their_poses_put_them(turn):
    centre = (1.0, -2.0, turn)
    near = (1.5, -1.0, turn + math.pi / 2)
    scans = [_scan(0, centre), _scan(1, near)]
    alone = Context(neighbours=1, spacing=0.5, matched=False)
    got = LocalMapper(scans, log_poses(scans), alone).points(0, 100)
    assert got.shape == (2 * _BEAMS, 2)
    own = scans[0].points()
    np.testing.assert_allclose(got[:_BEAMS], own)
    # The neighbour's beam ends, taken to the world and back into the centre scan's frame.
    world = se2.transform_points(np.array(near), scans[1].points())
    expect = se2.transform_points(se2.inverse(np.array(centre)), world)
    np.testing.assert_allclose(got[_BEAMS:], expect, atol=1e-9)
    # Without neighbours the side is the scan's own points, untouched.
    np.testing.assert_array_equal(LocalMapper(scans, log_poses(scans), Context()).points(0, 9), own)


def test_a_map_short_of_the_other_scan_holds_its_neighbours_whatever_was_asked_before():
    """A map that ends short of the pair's other scan is cut from the centre's whole walk
    when that was made first: the same points in the same order as one placed afresh."""
    scans = [_scan(i, (i * 0.25, 0.05 * math.sin(i), 0.03 * i)) for i in range(40)]
    context = Context(neighbours=3, spacing=0.5, matched=False)
    whole_first = LocalMapper(scans, log_poses(scans), context)
    whole = whole_first.points(20, 100)
    for other in (21, 23, 17, 100):
        short = whole_first.points(20, other)
        alone = LocalMapper(scans, log_poses(scans), context).points(20, other)
        np.testing.assert_array_equal(short, alone)
        count = len(neighbours(log_poses(scans), 20, other, context))
        assert len(short) == (1 + count) * _BEAMS
    assert len(whole) == 7 * _BEAMS and len(whole_first.points(20, 21)) < len(whole)


@pytest.fixture(scope="module")
def drifting_log(tmp_path_factory):
    """A simulated log whose odometry drifts from its true poses (``reference``)."""
    from vgm_studio.datasets import open_log
    from vgm_studio.simulation.simulate import SimConfig, simulate

    folder = tmp_path_factory.mktemp("drift")
    return open_log(simulate(SimConfig(preset="office", seed=3, num_beams=181, laps=0.3), folder))


def test_a_neighbour_is_matched_to_its_centre_from_a_poor_guess(drifting_log):
    scans = drifting_log.scans
    truth = log_poses(scans)
    # The log's odometry, each pose knocked a further 5 cm and 2° off at random.
    rng = np.random.default_rng(0)
    guesses = np.array([s.odometry for s in scans])
    guesses += rng.normal(0.0, [0.05, 0.05, math.radians(2.0)], guesses.shape)
    mapper = LocalMapper(scans, guesses, Context(neighbours=2))
    off_guess, off_match = [], []
    for centre in range(20, len(scans) - 20, 10):
        for j in neighbours(guesses, centre, len(scans) * 2, mapper.context):
            true = se2.between(truth[centre], truth[j])
            guess = se2.between(guesses[centre], guesses[j])
            off_guess.append(float(np.hypot(*(guess[:2] - true[:2]))))
            placed = mapper.placed(centre, j)
            if placed is not None:
                off_match.append(float(np.hypot(*(placed[:2] - true[:2]))))
    assert len(off_match) >= 0.8 * len(off_guess) >= 40
    assert np.median(off_match) < min(0.02, np.median(off_guess) / 3)
    assert np.percentile(off_match, 90) < 0.05


def test_a_neighbour_whose_match_does_not_hold_is_left_out(drifting_log):
    scans = list(drifting_log.scans)
    poses = log_poses(scans)
    context = Context(neighbours=2)
    centre = 40
    near = neighbours(poses, centre, 1000, context)
    assert near
    # One neighbour replaced by a scan of somewhere else (its ranges reversed, same pose).
    odd = near[0]
    scans[odd] = replace(scans[odd], ranges=scans[odd].ranges[::-1].copy())
    mapper = LocalMapper(scans, poses, context)
    assert mapper.placed(centre, odd) is None
    got = mapper.points(centre, 1000)
    kept = [j for j in near if mapper.placed(centre, j) is not None]
    assert len(got) == len(scans[centre].points()) + sum(len(scans[j].points()) for j in kept)


def test_labelled_edges_read_with_context_take_each_side_from_its_local_map(office_edges):
    from vgm_studio.datasets import open_log
    from vgm_studio.model.training import read_labelled

    context = Context(neighbours=2)
    plain = read_labelled([office_edges], progress=False)
    wide = read_labelled([office_edges], progress=False, context=context)
    alone = read_labelled([office_edges], progress=False, context=Context())
    log = open_log(plain.edges[0].log_path).scans
    mapper = LocalMapper(log, log_poses(log), context)
    grew = 0
    for edge, p, w, a in zip(plain.edges, plain.samples, wide.samples, alone.samples, strict=True):
        np.testing.assert_array_equal(a.prev, p.prev)  # no neighbours: the scans as before
        np.testing.assert_array_equal(a.cur, p.cur)
        prev = mapper.points(edge.a, edge.b)
        cur = se2.transform_points(np.array(edge.estimate), mapper.points(edge.b, edge.a))
        np.testing.assert_allclose(w.prev, prev.astype(np.float32))
        np.testing.assert_allclose(w.cur, cur.astype(np.float32), atol=1e-5)
        assert (w.inlier_ratio, w.residual) == (p.inlier_ratio, p.residual)
        grew += len(w.prev) > len(p.prev)
    assert grew > len(plain.edges) // 2


@pytest.mark.long
def test_a_model_trained_with_context_keeps_it_and_reads_edges_with_it(
    balanced_office_edges, tmp_path
):
    from vgm_studio.model.metrics import roc_auc
    from vgm_studio.model.training import read_labelled
    from vgm_studio.model.validator import Validator

    model = tmp_path / "context.pt"
    short = ("--epochs", "1", "--epoch-size", "64")
    trained = run(
        "train", balanced_office_edges, "--context", "2", "--no-covisible", *short, "--out", model
    )
    assert trained.returncode == 0, trained.stderr
    validator = Validator.load(model)
    assert validator.context == Context(neighbours=2)
    wide = read_labelled([balanced_office_edges], progress=False, context=validator.context)
    p = validator.predict(wide.edges)
    np.testing.assert_allclose(p, validator.predict_samples(wide.samples), atol=1e-6)
    report = tmp_path / "eval.json"
    judged = run("eval", model, balanced_office_edges, "--json", report)
    assert judged.returncode == 0, judged.stderr
    assert json.loads(report.read_text())["auc"] == pytest.approx(roc_auc(wide.labels, p))
    # Its weights read other inputs than a single-scan run's: no warm start from them.
    again = run("train", balanced_office_edges, "--init", model, *short, "--out", tmp_path / "b.pt")
    # stderr also carries training's first progress line, so not one_line_error here.
    assert again.returncode == 1 and "--init needs a vgmnet one" in again.stderr
    assert "Traceback" not in again.stderr
    bad = run("train", balanced_office_edges, "--context", "-1", "--out", tmp_path / "c.pt")
    assert "--context" in one_line_error(bad, 2)
    alone = run(
        "train", balanced_office_edges, "--context", "0", "--covisible", "--out", tmp_path / "d.pt"
    )
    assert "--covisible" in one_line_error(alone, 2) and "--context" in one_line_error(alone, 2)


def test_train_unasked_draws_vgmnet_as_the_bundled_model_is(balanced_office_edges, tmp_path):
    """``train`` without --context draws vgmnet's pairs as the bundled model's recipe does, so
    that a model trained with the defaults is one the background trainer can start from."""
    from vgm_studio.model.checkpoint import load_checkpoint
    from vgm_studio.model.context import DEFAULT_CONTEXT
    from vgm_studio.model.registry import BUNDLED_MODEL

    model = tmp_path / "unasked.pt"
    trained = run(
        "train", balanced_office_edges, "--epochs", "1", "--epoch-size", "64", "--out", model
    )
    assert trained.returncode == 0, trained.stderr
    bundled = load_checkpoint(BUNDLED_MODEL).context
    assert load_checkpoint(model).context == DEFAULT_CONTEXT == bundled


def _context_model(folder: Path) -> Path:
    """The bundled weights, declared to read two neighbours a side."""
    from vgm_studio.model.checkpoint import load_checkpoint, save_checkpoint
    from vgm_studio.model.registry import BUNDLED_MODEL

    checkpoint = load_checkpoint(BUNDLED_MODEL)
    checkpoint.context = Context(neighbours=2)
    save_checkpoint(folder / "context.pt", checkpoint)
    return folder / "context.pt"


def test_slam_feeds_a_local_map_model_each_keyframe_with_its_neighbours(tmp_path):
    from vgm_studio.datasets import open_log
    from vgm_studio.matching.matcher import ScanMatcher
    from vgm_studio.model.features import sample_from_scans
    from vgm_studio.model.validator import Validator
    from vgm_studio.simulation.simulate import SimConfig, simulate
    from vgm_studio.slam.config import ValidationConfig
    from vgm_studio.slam.edges import SlamEdge
    from vgm_studio.slam.validation import EdgeValidator, LocalMaps

    model = _context_model(tmp_path)
    log = open_log(simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=0.3), tmp_path))
    # The odometry, not the reference the log also has: the run's poses place the neighbours.
    poses = np.array([s.odometry for s in log.scans])
    keyframes = np.arange(0, len(log), 10)
    keyed = [log.scans[i] for i in keyframes]
    config = ValidationConfig(model=model, second_look=1, loop_threshold=None)
    validator = EdgeValidator(config, keyed, local=LocalMaps(log.scans, poses, keyframes))
    a, b = 3, 4
    match = ScanMatcher().match(keyed[a], keyed[b], se2.between(poses[30], poses[40]))
    edge = SlamEdge("sequential", a, b, match.estimate, match)
    validator([edge])
    context = Context(neighbours=2)
    mapper = LocalMapper(log.scans, poses, context)
    sides = [mapper.points(c, o) for c, o in ((30, 40), (40, 30))]
    assert all(len(side) > len(keyed[0].points()) for side in sides)
    want = Validator.load(model).predict_samples(
        [sample_from_scans(*sides, match.estimate, match.figures())]
    )
    assert edge.p_success == pytest.approx(float(want[0]), abs=1e-6)
    # Without where to find the neighbours, the validator is refused, not fed single scans.
    with pytest.raises(InputError, match="reads each scan with 2 neighbours a side"):
        EdgeValidator(config, keyed)


@pytest.mark.long
def test_slam_runs_with_a_local_map_model(tmp_path):
    model = _context_model(tmp_path)
    from vgm_studio.simulation.simulate import SimConfig, simulate

    log = simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=1.2), tmp_path)
    out = tmp_path / "out.json"
    proc = run("slam", log, "--model", model, "--json", out)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result["loops_kept"] > 0
    loops = [e for e in result["edges"] if e["kind"] == "loop"]
    assert all(0.0 <= e["p_success"] <= 1.0 for e in loops if e["p_success"] is not None)


def test_a_validator_reads_edges_with_its_own_context(office_edges):
    from vgm_studio.model.checkpoint import load_checkpoint
    from vgm_studio.model.registry import BUNDLED_MODEL
    from vgm_studio.model.training import read_labelled
    from vgm_studio.model.validator import Validator

    checkpoint = load_checkpoint(BUNDLED_MODEL)
    checkpoint.context = Context(neighbours=2)
    validator = Validator(checkpoint, device="cpu")
    wide = read_labelled([office_edges], progress=False, context=checkpoint.context)
    single = read_labelled([office_edges], progress=False)
    p = validator.predict(wide.edges)
    np.testing.assert_allclose(p, validator.predict_samples(wide.samples), atol=1e-6)
    # The bundled weights judge the local maps otherwise than the scans alone.
    assert np.abs(p - validator.predict_samples(single.samples)).max() > 0.01


def _half_ring(ranges: list[float], mount: LaserMount | None = None) -> Scan:
    """A laser looking ahead over 180° in beams 45° apart (-90°, -45°, 0°, 45°, 90°)."""
    r = np.array(ranges, np.float32)
    return Scan(0, 0.0, r, -math.pi / 2, math.pi / 4, 30.0, mount=mount)


def _at(bearing_deg: float, distance: float) -> list[float]:
    a = math.radians(bearing_deg)
    return [distance * math.cos(a), distance * math.sin(a)]


def test_a_point_is_seen_inside_the_view_up_to_the_beam_and_its_margin():
    # The beam at 0° hit a wall 2 m ahead; the one at +45° had no return (30 m max range).
    scan = _half_ring([2.0, 2.0, 2.0, 30.0, 2.0])
    points = np.array(
        [
            _at(0, 1.0),  # in front of the wall
            _at(0, 2.2),  # behind it, within the 0.3 m margin
            _at(0, 2.5),  # behind it, beyond the margin: the laser never saw there
            _at(45, 20.0),  # along a beam without a return: free space to 30 m
            _at(45, 31.0),  # beyond the laser's range
            _at(180, 1.0),  # behind the laser, outside its 180° view
            _at(-120, 1.0),  # outside the view: more than half a beam past the -90° one
        ]
    )
    assert seen_by(scan, points, 0.3).tolist() == [True, True, False, True, False, False, False]
    assert seen_by(scan, points, 0.6)[2]  # a wider margin takes it in


def test_the_compiled_test_is_numpys_point_for_point():
    rng = np.random.default_rng(5)
    ranges = rng.uniform(0.5, 8.0, 181).astype(np.float32)
    ranges[rng.random(181) < 0.2] = 30.0  # no return
    ranges[:3] = 0.0  # too short to be a point
    scan = Scan(0, 0.0, ranges, -math.pi / 2, math.pi / 180, 30.0)
    points = rng.uniform(-35, 35, (20_000, 2))
    bearing = np.arctan2(points[:, 1], points[:, 0])
    beam = np.rint(se2.wrap_angle(bearing - scan.angle_min) / scan.angle_increment)
    beam = np.where(beam < 0, beam + round(2 * math.pi / abs(scan.angle_increment)), beam)
    inside = (beam >= 0) & (beam < scan.num_beams)
    reach = np.where(scan.valid(), scan.ranges, scan.max_range).astype(np.float64)
    idx = np.clip(beam, 0, scan.num_beams - 1).astype(np.int64)
    numpy = inside & (np.hypot(points[:, 0], points[:, 1]) <= reach[idx] + 0.3)
    assert 0 < numpy.sum() < len(points)
    np.testing.assert_array_equal(seen_by(scan, points, 0.3), numpy)


def test_what_a_mounted_laser_saw_is_judged_in_the_laser_frame():
    """The same beams from a laser 0.5 m ahead of the base, turned 90° and upside down: a
    point is seen exactly where its place in the laser frame is."""
    mount = LaserMount(x=0.5, y=0.0, yaw=math.pi / 2, flipped=True)
    bare, mounted = (
        _half_ring([2.0, 1.0, 2.0, 30.0, 2.0]),
        _half_ring([2.0, 1.0, 2.0, 30.0, 2.0], mount),
    )
    laser = np.random.default_rng(0).uniform(-3, 3, size=(400, 2))
    np.testing.assert_array_equal(
        seen_by(mounted, mount.place(laser), 0.3), seen_by(bare, laser, 0.3)
    )
    assert 0 < seen_by(bare, laser, 0.3).sum() < len(laser)


def test_covisible_sides_keep_the_scans_and_drop_neighbours_the_other_never_saw():
    """Scans along +x, each seeing a ring 2 m around it: a neighbour's points the other
    side's scan could not see (farther than 2.3 m from it) are dropped; its scan stays whole."""
    scans = _line(40, 0.25)
    poses = log_poses(scans)
    plain = LocalMapper(scans, poses, Context(neighbours=2, matched=False))
    crop = LocalMapper(scans, poses, Context(neighbours=2, matched=False, covisible=True))
    a, b = 10, 30
    estimate = se2.between(poses[a], poses[b])  # type: ignore[arg-type]
    wide_a, wide_b = plain.sides(a, b, estimate)
    np.testing.assert_array_equal(wide_a, plain.points(a, b))
    prev, cur = crop.sides(a, b, estimate)
    own_a, own_b = scans[a].points(), scans[b].points()
    np.testing.assert_array_equal(prev[: len(own_a)], own_a)
    np.testing.assert_array_equal(cur[: len(own_b)], own_b)
    # Every neighbour point kept lies within b's view (2 m + 0.3 m of b), every one dropped
    # outside it; b is 5 m ahead of a, so a's ring-of-2-m neighbours are partly dropped.
    in_b = se2.transform_points(se2.inverse(estimate), wide_a[len(own_a) :])
    near = np.hypot(in_b[:, 0], in_b[:, 1]) <= 2.3
    assert 0 < near.sum() < len(near)
    assert len(prev) == len(own_a) + near.sum()
    assert len(cur) < len(wide_b)


def test_a_checkpoint_keeps_the_covisible_crop_and_older_ones_read_without_it():
    from vgm_studio.model.checkpoint import Checkpoint

    cropped = Context(neighbours=2, covisible=True, view_margin=0.2)
    saved = Checkpoint(model="vgmnet", context=cropped).to_dict()
    assert Checkpoint.from_dict(saved).context == cropped
    older = {k: v for k, v in saved["context"].items() if k not in ("covisible", "view_margin")}
    assert Checkpoint.from_dict({**saved, "context": older}).context == Context(neighbours=2)


def test_neighbours_placed_ahead_in_a_worker_process_are_those_placed_here(tmp_path, monkeypatch):
    """``PlacingAhead`` places every keyframe's neighbours in a spawned process: the mapper
    that takes them holds, bit for bit, what it would have placed itself; a worker that dies
    leaves the mapper placing the rest itself, with no error."""
    import time

    from vgm_studio.datasets import open_log
    from vgm_studio.simulation.simulate import SimConfig, simulate
    from vgm_studio.slam.placing import PlacingAhead

    log = open_log(simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=0.3), tmp_path))
    poses = np.array([s.odometry for s in log.scans])
    keyframes = np.arange(0, len(log), 7)
    context = Context(neighbours=2, covisible=True)
    here = LocalMapper(log.scans, poses, context)
    maps = [here.points(int(k), 10**6) for k in keyframes]
    worked = LocalMapper(log.scans, poses, context)
    ahead = PlacingAhead(worked, keyframes)
    deadline = time.monotonic() + 60
    while ahead._pending and time.monotonic() < deadline:
        time.sleep(0.1)
        ahead.collect()
    ahead.close()
    assert set(here._placed) <= set(worked._placed)  # all of it came from the worker
    assert any(v is not None for v in worked._placed.values())
    for key, pose in here._placed.items():
        got = worked._placed[key]
        assert (pose is None) == (got is None) and (pose is None or np.array_equal(pose, got))
    for k, want in zip(keyframes, maps, strict=True):
        assert np.array_equal(worked.points(int(k), 10**6), want)
    # A worker killed before it sent anything: the mapper places every neighbour itself.
    alone = LocalMapper(log.scans, poses, context)
    dead = PlacingAhead(alone, keyframes)
    assert dead._pool is not None
    for process in dead._pool._processes.values():  # started by the first job
        process.kill()
    deadline = time.monotonic() + 30
    while dead._pending and time.monotonic() < deadline:
        time.sleep(0.1)
        dead.collect()
    assert not dead._pending and dead._pool is None and not alone._placed  # given up
    for k, want in zip(keyframes, maps, strict=True):
        assert np.array_equal(alone.points(int(k), 10**6), want)
    # Where no process can be started at all, there is no worker and no error either.
    import multiprocessing

    def no_processes(_method: str) -> None:
        raise OSError("no /dev/shm")

    monkeypatch.setattr(multiprocessing, "get_context", no_processes)
    bare = LocalMapper(log.scans, poses, context)
    none = PlacingAhead(bare, keyframes)
    none.collect()
    assert none._pool is None and not none._pending
    assert np.array_equal(bare.points(int(keyframes[0]), 10**6), maps[0])


_PARENT = """
import sys, time
import numpy as np
from vgm_studio.datasets import open_log
from vgm_studio.model.context import Context, LocalMapper
from vgm_studio.slam.placing import PlacingAhead

log = open_log(sys.argv[1])
poses = np.array([s.odometry for s in log.scans])
mapper = LocalMapper(log.scans, poses, Context(neighbours=2))
ahead = PlacingAhead(mapper, np.arange(len(log)))
print(*ahead._pool._processes, flush=True)
time.sleep(600)
"""


def test_a_worker_whose_parent_is_killed_outright_goes_too(tmp_path):
    """kill -9 closes no pipe the worker waits on, so the worker watches its parent and goes
    when it does: no orphan left placing neighbours for nobody."""
    from orphans import assert_worker_goes_with_its_parent

    from vgm_studio.simulation.simulate import SimConfig, simulate

    log = simulate(SimConfig(preset="loop", seed=2, num_beams=181, laps=0.3), tmp_path)
    assert_worker_goes_with_its_parent(_PARENT, log)
