"""The laser's mount: from /tf_static, /tf or the options; scans placed in the base frame;
the warning when scans and odometry disagree. Bags of a simulated robot whose laser sits
0.3 m ahead of the base, upside down (tests/simbags.py)."""

from __future__ import annotations

import dataclasses
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability
from simbags import SimBag, simulate_run, write_sim_bag

from vgm_studio.core import se2
from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.datasets.mount import LaserMount, mount_from_matrix, parse_laser_pose
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.matching.agreement import (
    check_agreement,
    check_log,
    disagreement_warning,
    edges_agreement,
)
from vgm_studio.matching.candidates import CandidateConfig, make_candidates
from vgm_studio.matching.edges import Edge, edge_id
from vgm_studio.matching.matcher import ScanMatcher

MOUNT = (0.3, 0.0, 0.0, True)  # 0.3 m ahead, facing forward, upside down
OPTIONS = ReadOptions(laser_pose=(0.3, 0.0, 0.0), laser_flipped=True)


@pytest.fixture(scope="module")
def run_sim() -> SimBag:
    return simulate_run(MOUNT)


def cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("vgm-studio")
    cmd = [exe] if exe else [sys.executable, "-m", "vgm_studio.tools.cmd"]
    return subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True, timeout=600)


def sequential_errors(log: ScanLog, truth: np.ndarray) -> tuple[list[Edge], np.ndarray]:
    """Sequential edges of every scan pair, and each one's distance from the true motion."""
    edges = make_candidates(log, ScanMatcher(), CandidateConfig(loops=False), progress=False)
    errors = [math.dist(e.estimate[:2], se2.between(truth[e.a], truth[e.b])[:2]) for e in edges]
    return edges, np.array(errors)


def assert_agrees_to_a_centimetre(log: ScanLog, truth: np.ndarray) -> list[Edge]:
    edges, errors = sequential_errors(log, truth)
    assert len(edges) == len(truth) - 1
    assert np.median(errors) <= 0.01, np.median(errors)
    assert np.percentile(errors, 90) <= 0.01, np.percentile(errors, 90)
    return edges


@pytest.mark.parametrize("ros2", [False, True], ids=["rosbag1", "rosbag2-transient-local"])
def test_mount_from_tf_static_agrees_with_odometry(
    tmp_path: Path, run_sim: SimBag, ros2: bool
) -> None:
    path = write_sim_bag(
        tmp_path / ("run" if ros2 else "run.bag"), run_sim, tf_mount=MOUNT, ros2=ros2
    )
    log = open_log(path)
    assert log.mount is not None
    assert (log.mount.x, log.mount.y, log.mount.yaw) == pytest.approx((0.3, 0.0, 0.0), abs=1e-9)
    assert log.mount.flipped
    assert log.mount_source is not None and "/tf_static" in log.mount_source
    assert log.message_counts["/tf_static"] == 1
    edges = assert_agrees_to_a_centimetre(log, run_sim.truth)
    agreement = check_agreement(log, _motions(edges))
    assert agreement is not None and not agreement.disagrees
    # The mount is in every edge's params and its id.
    assert edges[0].params["mount"]["flipped"] is True
    assert edges[0].params["mount"]["x"] == pytest.approx(0.3)
    e = edges[0]
    assert e.edge_id != edge_id(log.content_hash, e.a, e.b, e.estimate)
    assert e.edge_id == edge_id(log.content_hash, e.a, e.b, e.estimate, log.mount.id_text())


def test_ros2_tf_static_is_transient_local(tmp_path: Path, run_sim: SimBag) -> None:
    path = write_sim_bag(tmp_path / "run", run_sim, tf_mount=MOUNT, ros2=True)
    with AnyReader([path]) as reader:
        (tf,) = [c for c in reader.connections if c.topic == "/tf_static"]
        qos = tf.ext.offered_qos_profiles  # type: ignore[union-attr]
    assert [q.durability for q in qos] == [QosDurability.TRANSIENT_LOCAL]
    assert (
        open_log(path).mount
        == open_log(write_sim_bag(tmp_path / "r.bag", run_sim, tf_mount=MOUNT)).mount
    )


def test_without_tf_the_warning_names_the_options_and_the_options_fix_it(
    tmp_path: Path, run_sim: SimBag
) -> None:
    path = write_sim_bag(tmp_path / "run.bag", run_sim, tf_mount=None)
    plain = open_log(path)
    assert plain.mount is None and plain.mount_source == "the bag has no /tf or /tf_static"
    edges, _ = sequential_errors(plain, run_sim.truth)
    agreement = edges_agreement(plain, edges)
    assert agreement is not None and agreement.heading_disagrees
    warning = disagreement_warning(plain, agreement)
    assert warning is not None and "\n" not in warning and warning.startswith("warning: ")
    assert "--laser-pose" in warning and "--laser-flipped" in warning
    assert "--odom-topic" in warning and "wheel slip" in warning
    # With odometry on some scans only, nothing uses it, so the same figures warn of nothing.
    partial = dataclasses.replace(
        plain,
        scans=[
            s if i % 2 else dataclasses.replace(s, odometry=None) for i, s in enumerate(plain.scans)
        ],
    )
    assert disagreement_warning(partial, agreement) is None

    given = open_log(path, OPTIONS)
    assert given.mount == LaserMount(0.3, 0.0, 0.0, True)
    edges = assert_agrees_to_a_centimetre(given, run_sim.truth)
    assert disagreement_warning(given, edges_agreement(given, edges)) is None


def test_info_check_and_candidates_print_the_warning(tmp_path: Path, run_sim: SimBag) -> None:
    path = write_sim_bag(tmp_path / "run.bag", run_sim, tf_mount=None)
    check = cli("info", path, "--check")
    assert check.returncode == 0, check.stderr
    assert check.stdout.startswith("warning: the scans and odometry disagree")
    assert "--laser-pose" in check.stdout
    fixed = cli("info", path, "--check", "--laser-pose", "0.3,0,0", "--laser-flipped")
    assert fixed.returncode == 0 and "agree" in fixed.stdout and "warning" not in fixed.stdout
    table = cli("info", path, "--laser-pose", "0.3,0,0", "--laser-flipped").stdout
    assert "--laser-pose 0.3,0,0 --laser-flipped (given by" in table
    out = cli("candidates", path, "--out", tmp_path / "e.jsonl", "--no-loops")
    assert out.returncode == 0, out.stderr
    assert out.stderr.count("warning: the scans and odometry disagree") == 1
    bad = cli("info", path, "--laser-pose", "0.3,0")
    assert bad.returncode == 2 and "--laser-pose" in bad.stderr and "Traceback" not in bad.stderr


def test_dynamic_tf_gives_the_mount_at_each_scan(tmp_path: Path, run_sim: SimBag) -> None:
    path = write_sim_bag(tmp_path / "run.bag", run_sim, tf_mount=MOUNT, static=False)
    log = open_log(path)
    assert log.mount_source is not None and log.mount_source.startswith("from /tf,")
    assert all(s.mount == log.mount for s in log.scans)
    assert log.mount is not None and log.mount.flipped
    agreement = check_log(log)
    assert agreement is not None and not agreement.disagrees


def still_bag(tmp_path: Path) -> Path:
    return write_sim_bag(
        tmp_path / "still.bag", simulate_run(MOUNT, scans=30, still=True), tf_mount=MOUNT
    )


def test_still_robot_slam_record_exits_zero(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    rrd = tmp_path / "still.rrd"
    proc = cli(
        "slam", still_bag(tmp_path), "--validator", "none", "--record", rrd, "--map-png", tmp_path
    )
    assert proc.returncode == 0, proc.stderr
    assert "one keyframe" in proc.stderr and "Traceback" not in proc.stderr
    assert len(RrdReader(rrd).stream().collect()) > 0
    assert (tmp_path / "after.png").is_file()


def test_still_robot_slam_candidates_and_check_finish(tmp_path: Path) -> None:
    path = still_bag(tmp_path)
    proc = cli(
        "slam", path, "--validator", "none", "--map-png", tmp_path, "--json", tmp_path / "r.json"
    )
    assert proc.returncode == 0, proc.stderr
    assert "one keyframe" in proc.stderr and "Traceback" not in proc.stderr
    assert (tmp_path / "after.png").is_file() and (tmp_path / "r.json").is_file()
    edges = cli("candidates", path, "--out", tmp_path / "e.jsonl")
    assert edges.returncode == 0, edges.stderr
    assert "warning" not in edges.stderr  # a still robot agrees with still wheels
    check = cli("info", path, "--check")
    assert check.returncode == 0 and "the robot does not move" in check.stdout


def test_no_odometry_says_none(tmp_path: Path, run_sim: SimBag) -> None:
    path = write_sim_bag(tmp_path / "run.bag", run_sim, tf_mount=None, odometry=False)
    table = cli("info", path).stdout
    assert "odometry          none" in table and "travelled" not in table
    check = cli("info", path, "--check")
    assert check.returncode == 0 and "the log has no odometry" in check.stdout


def _motions(edges: list[Edge]):  # type: ignore[no-untyped-def]
    from vgm_studio.matching.agreement import motions_of

    return motions_of(
        [(e.a, e.b) for e in edges],
        [e.estimate for e in edges],
        [e.match.get("covariance") for e in edges],
    )


def test_mount_geometry() -> None:
    """Roll π mirrors y; pitch π is a mirror turned half round; yaw turns the scan."""
    roll = np.diag([1.0, -1.0, -1.0, 1.0])
    roll[:3, 3] = [0.2, 0.1, 0.3]
    m = mount_from_matrix(roll)
    assert m.flipped and (m.x, m.y, m.yaw) == pytest.approx((0.2, 0.1, 0.0))
    assert m.place(np.array([[1.0, 2.0]])) == pytest.approx(np.array([[1.2, -1.9]]))
    pitch = mount_from_matrix(np.diag([-1.0, 1.0, -1.0, 1.0]))
    assert pitch.flipped and abs(pitch.yaw) == pytest.approx(math.pi)
    assert pitch.place(np.array([[1.0, 2.0]])) == pytest.approx(np.array([[-1.0, 2.0]]))
    turned = LaserMount(0.0, 0.0, math.pi / 2)
    assert turned.place(np.array([[1.0, 0.0]])) == pytest.approx(np.array([[0.0, 1.0]]))
    assert LaserMount().is_base and LaserMount().id_text() == ""
    assert parse_laser_pose(" 0.2, 0 ,180") == (0.2, 0.0, 180.0)
    for bad in ("0.2,0", "a,b,c", "0,0,nan", ""):
        with pytest.raises(ValueError, match="X,Y,YAW"):
            parse_laser_pose(bad)


def test_carmen_options_keep_the_world_where_the_log_put_it(tmp_path: Path) -> None:
    """A CARMEN log's poses are the laser's: a mount moves them to the base, not the world."""
    from vgm_studio.simulation import SimConfig, simulate

    path = simulate(SimConfig(preset="corridor", laps=0.05, num_beams=91), tmp_path)
    plain = open_log(path)
    mounted = open_log(path, ReadOptions(laser_pose=(0.3, 0.1, 30.0)))
    assert plain.mount is None and mounted.mount == LaserMount(0.3, 0.1, math.radians(30.0))
    for a, b in zip(plain.scans[:20], mounted.scans[:20], strict=True):
        assert a.odometry is not None and b.odometry is not None
        world_a = se2.transform_points(a.odometry, a.points())
        world_b = se2.transform_points(b.odometry, b.points())
        np.testing.assert_allclose(world_b, world_a, atol=1e-9)
        assert b.reference is not None and a.reference is not None
        np.testing.assert_allclose(
            se2.compose(b.reference, mounted.mount.pose),
            a.reference,
            atol=1e-9,  # type: ignore[union-attr]
        )


def test_edges_of_a_log_at_the_base_keep_their_ids(tmp_path: Path) -> None:
    from vgm_studio.simulation import SimConfig, simulate

    path = simulate(SimConfig(preset="corridor", laps=0.03, num_beams=91), tmp_path)
    log = open_log(path)
    edges = make_candidates(log, ScanMatcher(), CandidateConfig(loops=False), progress=False)
    assert edges and all(e.params["mount"] is None for e in edges)
    for e in edges:  # the id formula from before mounts existed
        assert e.edge_id == edge_id(log.content_hash, e.a, e.b, e.estimate)


def test_unreadable_bag_is_one_line_on_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "old.bag"
    path.write_bytes(b"#ROSRECORD V1.2\n" + bytes(4096))
    proc = cli("info", path)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert "older than 2.0" in lines[0] and "rosbag fix" in lines[0]


def test_a_reference_log_takes_the_same_mount(tmp_path: Path) -> None:
    """A CARMEN reference's poses are the laser's too: joined to a mounted log, they move to
    the base with the same mount, so labels compare poses of one frame."""
    from vgm_studio.datasets.source import read_source
    from vgm_studio.simulation import SimConfig, simulate

    path = simulate(SimConfig(preset="corridor", laps=0.03, num_beams=91), tmp_path)
    options = ReadOptions(poses="odometry", laser_pose=(0.3, 0.1, 30.0))
    plain = read_source(path, ReadOptions(poses="odometry"), reference=path).log
    mounted = read_source(path, options, reference=path).log
    assert mounted.mount is not None
    for a, b in zip(plain.scans, mounted.scans, strict=True):
        assert a.reference is not None and b.reference is not None
        np.testing.assert_allclose(
            se2.compose(b.reference, mounted.mount.pose), a.reference, atol=1e-9
        )


def test_a_laser_facing_backwards_disagrees_in_translation(tmp_path: Path) -> None:
    """Turned half round and not declared, the scans see the robot drive backwards."""
    backwards = (0.0, 0.0, math.pi, False)
    path = write_sim_bag(tmp_path / "run.bag", simulate_run(backwards), tf_mount=None)
    agreement = check_log(open_log(path))
    assert agreement is not None and agreement.translation_disagrees
    assert agreement.median_disagreement > 0.3  # two 0.25 m keyframe steps' worth, nearly
    given = open_log(path, ReadOptions(laser_pose=(0.0, 0.0, 180.0)))
    fixed = check_log(given)
    assert fixed is not None and not fixed.disagrees


def test_ordinary_wheel_noise_raises_no_warning(tmp_path: Path) -> None:
    """The simulator's default wheel noise and drift (2%/√m, 0.5°/√m, 0.05°/m) is within
    the check's allowance: a correctly mounted laser gives no warning."""
    run = simulate_run(MOUNT, noisy_odometry=True)
    assert np.abs(run.odometry - run.truth).max() > 0.01  # the wheels do drift
    log = open_log(write_sim_bag(tmp_path / "run.bag", run, tf_mount=MOUNT))
    edges, _ = sequential_errors(log, run.truth)
    assert not check_agreement(log, _motions(edges)).disagrees  # type: ignore[union-attr]
    checked = check_log(log)
    assert checked is not None and not checked.disagrees
