"""``vgm-studio slam``'s standard outputs, opened by the tools engineers open them with: the TUM
trajectory by evo, the ROS map as map_server reads its PGM and YAML, the g2o graph by gtsam."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml
from evo.tools import file_interface

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.datasets.tum import read_tum, write_tum
from vgm_studio.errors import InputError
from vgm_studio.simulation.presets import build_world
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.tools import cmd


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """The 12 m × 5 m corridor loop, a little over one lap (~380 scans, a second of SLAM)."""
    return simulate(SimConfig(preset="demo", seed=2, num_beams=181), tmp_path_factory.mktemp("d"))


@pytest.fixture(scope="module")
def outputs(demo, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("out")
    cmd.main(
        [
            "slam", str(demo),
            "--validator", "reference",
            "--json", str(out / "run.json"),
            "--trajectory", str(out / "traj.txt"),
            "--ros-map", str(out / "ros"),
            "--g2o", str(out / "after.g2o"),
        ]
    )  # fmt: skip
    return out


def _evo(tool: str, *args: str | Path) -> subprocess.CompletedProcess[str]:
    """An evo command line tool of this Python's environment, as a user runs it."""
    exe = Path(sys.executable).parent / tool
    found = str(exe) if exe.exists() else shutil.which(tool)
    assert found is not None, f"{tool} not installed (pip install evo: the test extra has it)"
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run(
        [found, *map(str, args)], capture_output=True, text=True, env=env, timeout=120
    )


def _tum_by_hand(path: Path, times: np.ndarray, poses: np.ndarray) -> Path:
    """A TUM file written from the format's definition, not by the code under test."""
    with path.open("w") as f:
        for t, (x, y, th) in zip(times, poses, strict=True):
            f.write(f"{t:.6f} {x} {y} 0 0 0 {np.sin(th / 2)} {np.cos(th / 2)}\n")
    return path


def _ape_rmse(ref: Path, est: Path) -> float:
    done = _evo("evo_ape", "tum", ref, est, "-a")
    assert done.returncode == 0, done.stderr
    found = re.search(r"^\s*rmse\s+([0-9.eE+-]+)\s*$", done.stdout, re.MULTILINE)
    assert found is not None, done.stdout
    return float(found.group(1))


def test_evo_reads_the_trajectory_of_every_scan_and_finds_it_near_the_truth(
    demo, outputs, tmp_path
):
    log = open_log(demo)
    truth, odometry = log.reference_poses(), log.odometry_poses()
    assert truth is not None and odometry is not None
    traj = outputs / "traj.txt"
    shown = _evo("evo_traj", "tum", traj)
    assert shown.returncode == 0, shown.stderr
    assert f"{len(log)} poses" in shown.stdout
    # evo's own reader: one pose per scan, at the scan's timestamp, flat on the ground.
    read = file_interface.read_tum_trajectory_file(str(traj))
    np.testing.assert_array_equal(read.timestamps, log.timestamps)
    np.testing.assert_array_equal(read.positions_xyz[:, 2], 0.0)
    np.testing.assert_allclose(np.linalg.norm(read.orientations_quat_wxyz, axis=1), 1.0, atol=1e-8)
    ours = read_tum(traj)
    np.testing.assert_allclose(ours.poses[:, :2], read.positions_xyz[:, :2], atol=1e-12)
    # Against the simulator's truth (evo aligns the frames: SLAM's starts at the first scan).
    ref = _tum_by_hand(tmp_path / "truth.txt", log.timestamps, truth)
    after = _ape_rmse(ref, traj)
    odo = _ape_rmse(ref, _tum_by_hand(tmp_path / "odometry.txt", log.timestamps, odometry))
    assert after < 0.03, after
    # The loops closed: the graph's trajectory is well inside the odometry's drift (0.08 m).
    assert after < odo / 3, (after, odo)


def _read_pgm(path: Path) -> np.ndarray:
    """A binary 8-bit PGM as map_server reads one, each part of the header checked."""
    data = path.read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:
        while data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end : end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    magic, width, height, maxval = fields
    assert magic == b"P5" and maxval == b"255"
    pixels = data[pos + 1 :]  # one whitespace byte after the maximum value
    w, h = int(width), int(height)
    assert len(pixels) == w * h
    return np.frombuffer(pixels, dtype=np.uint8).reshape(h, w)


def test_the_ros_map_puts_the_simulated_walls_on_their_pixels(demo, outputs):
    folder = outputs / "ros"
    meta = yaml.safe_load((folder / "map.yaml").read_text())
    assert meta["image"] == "map.pgm" and meta["negate"] == 0 and meta["mode"] == "trinary"
    assert (meta["occupied_thresh"], meta["free_thresh"]) == (0.65, 0.196)
    assert meta["origin"][2] == 0.0
    image = _read_pgm(folder / meta["image"])
    assert set(np.unique(image)) <= {0, 205, 254}
    res, (ox, oy) = meta["resolution"], meta["origin"][:2]
    assert res == 0.05
    log = open_log(demo)
    truth = log.reference_poses()
    assert truth is not None
    # SLAM's frame is the first scan's; the world's walls move into it by its true pose.
    to_map = se2.inverse(truth[0])

    def pixel(x: float, y: float) -> int:
        mx, my = se2.transform_points(to_map, np.array([[x, y]]))[0]
        col, up = int(np.floor((mx - ox) / res)), int(np.floor((my - oy) / res))
        return int(image[image.shape[0] - 1 - up, col])  # row 0 is the top: the highest y

    walls = build_world("demo").walls

    def on_a_wall(x: float, y: float) -> bool:
        x1, y1, x2, y2 = walls.T
        along = (np.minimum(x1, x2) <= x) & (x <= np.maximum(x1, x2))
        across = (np.minimum(y1, y2) <= y) & (y <= np.maximum(y1, y2))
        return bool(np.any(along & across))

    # Wall surfaces, each probed half a cell behind it (seen from the corridor) and half a cell
    # in front: beams end on the surface, so one of the two cells is hit and never crossed.
    # Which one depends on where the map puts the wall within that cell: its frame is the
    # first scan's, and 0.2° of heading there moves a wall 6 m away by 2 cm.
    half = res / 2
    for (x, y), behind in (
        ((13.0, 2.5), (half, 0.0)),  # the east corridor's outer wall
        ((6.0, -1.0), (0.0, -half)),  # the south corridor's outer wall, between two doors
        ((6.0, 6.0), (0.0, half)),  # the north corridor's
        ((6.0, 1.0), (0.0, half)),  # the inside of the loop, seen from the south
    ):
        assert on_a_wall(x, y)
        probes = [pixel(x + side * behind[0], y + side * behind[1]) for side in (1, -1)]
        assert 0 in probes, (x, y, probes)
    # Corridor centre lines are free; the solid block the loop goes round was never seen.
    # South above north (not mirrored) is what tells the first row is the top.
    for x, y in ((12.0, 2.5), (6.0, 0.0), (6.0, 5.0), (0.0, 2.5)):
        assert pixel(x, y) == 254, (x, y)
    assert pixel(6.0, 2.5) == 205


def test_gtsam_reads_the_g2o_graph_that_slam_solved(outputs):
    doc = json.loads((outputs / "run.json").read_text())
    path = str(outputs / "after.g2o")
    graph, initial = gtsam.readG2o(path, False)
    assert initial.size() == doc["keyframes"]
    # The after graph's factors: the kept edges, and odometry for each rejected sequential one.
    expected = sorted(
        (e["a"], e["b"]) for e in doc["edges"] if e["kept"] or e["kind"] == "sequential"
    )
    between = [graph.at(i) for i in range(graph.size())]
    assert sorted(tuple(f.keys()) for f in between) == expected
    # The vertices are that graph's optimum: gtsam started there moves them by micrometres.
    pin = gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
    graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0), pin))
    solved = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    moved = max(
        np.linalg.norm(solved.atPose2(k).translation() - initial.atPose2(k).translation())
        for k in range(initial.size())
    )
    assert moved < 1e-3, moved


def test_a_log_without_increasing_timestamps_gets_the_scan_index_as_time(demo, tmp_path, capsys):
    # Every scan stamped alike, as a log recorded without a clock reads; no TRUEPOS.
    lines = []
    for line in demo.read_text().splitlines():
        tokens = line.split()
        if not tokens or tokens[0] == "TRUEPOS" or tokens[0].startswith("#"):
            continue
        tokens[-3] = tokens[-1] = "5.000000"
        lines.append(" ".join(tokens))
    flat = tmp_path / "flat.log"
    flat.write_text("\n".join(lines) + "\n")
    out = tmp_path / "traj.txt"
    cmd.main(["slam", str(flat), "--validator", "none", "--trajectory", str(out)])
    said = capsys.readouterr()
    warned = [line for line in said.err.splitlines() if "scan index" in line]
    assert len(warned) == 1 and warned[0].startswith(f"{flat}: the scan timestamps")
    assert f"wrote {out}" in said.out
    read = read_tum(out)
    np.testing.assert_array_equal(read.timestamps, np.arange(len(read)))
    assert len(read) == len(open_log(flat))


def test_write_then_read_gives_the_poses_back(tmp_path):
    times = np.array([1.0e9 + 0.123456, 1.0e9 + 0.2, 1.0e9 + 7.5])
    poses = np.array([[0.0, 0.0, 0.0], [1.5, -2.25, 3.1], [-4.0, 8.0, -3.1]])
    path = tmp_path / "t.txt"
    write_tum(path, times, poses)
    read = read_tum(path)
    # Timestamps exactly (they tie poses to scans), poses to the printed digits.
    np.testing.assert_array_equal(read.timestamps, times)
    np.testing.assert_allclose(read.poses, poses, atol=1e-6)
    np.testing.assert_array_equal(read.lines, [2, 3, 4])  # line 1 is the header comment
    with pytest.raises(ValueError, match="increasing"):
        write_tum(tmp_path / "u.txt", times[::-1], poses)


GOOD = "1.0 0 0 0 0 0 0 1\n"


FIELDS_8 = "expected 8 fields (timestamp x y z qx qy qz qw), found 7"
NOT_UNIT = "the quaternion (qx qy qz qw) has length 0.7071, not 1"


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        (GOOD + "\n# fine\n2.0 1 2 0 0 0 1\n", 4, FIELDS_8),
        (GOOD + "2.0 1 two 0 0 0 0 1\n", 2, "y is not a number: 'two'"),
        (GOOD + "2.0 nan 0 0 0 0 0 1\n", 2, "x is not finite: nan"),
        (GOOD + "inf 0 0 0 0 0 0 1\n", 2, "timestamp is not finite: inf"),
        (GOOD + "2.0 0 0 0 0 0 0.5 0.5\n", 2, NOT_UNIT),
        (GOOD + "0.5 0 0 0 0 0 0 1\n", 2, "timestamp 0.5 goes back from line 1's (1.0)"),
        (GOOD + GOOD, 2, "timestamp 1.0 repeats line 1's (1.0)"),
        ("# only a comment\n\n", None, "no poses"),
        ("", None, "no poses"),
    ],
)
def test_each_bad_tum_file_is_one_line_naming_file_and_line(tmp_path, text, line, message):
    path = tmp_path / "traj.txt"
    path.write_text(text)
    with pytest.raises(InputError) as caught:
        read_tum(path)
    said = str(caught.value)
    assert "\n" not in said
    where = f"{path}:{line}: " if line is not None else f"{path}: "
    assert said.startswith(where + message), said
    assert caught.value.line == line


def test_a_missing_or_binary_tum_file_is_named(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_tum(tmp_path / "nope.txt")
    binary = tmp_path / "bin.txt"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputError, match="not a text file"):
        read_tum(binary)


@pytest.mark.parametrize(
    ("option", "target", "message"),
    [
        ("--ros-map", "file", "is a file, not a folder; --ros-map takes a folder"),
        ("--trajectory", "folder", "is a folder; give a file name to write"),
        ("--g2o", "folder", "is a folder; give a file name to write"),
    ],
)
def test_an_output_that_cannot_be_written_fails_before_the_run(
    demo, tmp_path, option, target, message
):
    existing = tmp_path / "file"
    existing.write_text("")
    named = existing if target == "file" else tmp_path
    done = subprocess.run(
        [sys.executable, "-m", "vgm_studio.tools.cmd", "slam", str(demo), option, str(named)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines() == [f"vgm-studio: error: {named}: {message}"]
    assert "edges:" not in done.stdout  # refused before the log was read
