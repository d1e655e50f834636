"""The mount a CARMEN log declares (``PARAM robot_frontlaser_offset`` and its kin) places its
scans and poses at the robot's centre, as tf does for a bag; ``--laser-pose`` still wins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.datasets.carmen import flaser_angles
from vgm_studio.errors import InputError
from vgm_studio.tools import cmd


def _flaser(pose: tuple[float, float, float], t: float, beams: int = 181) -> str:
    # The last beam's longer reading sets the log's maximum range above the others'.
    ranges = " ".join(["2.0"] * (beams - 1) + ["5.0"])
    x, y, th = pose
    return f"FLASER {beams} {ranges} {x} {y} {th} {x} {y} {th} {t} h {t}"


def _log(path: Path, params: list[str], after: tuple[str, ...] = ()) -> Path:
    poses = [(0.0, 0.0, 0.0), (0.5, 0.1, 0.3), (1.0, 0.3, 0.6)]
    lines = [f"PARAM {p} nohost 0" for p in params]
    lines.append(_flaser(poses[0], 1.0))
    lines += [f"PARAM {p} nohost 0" for p in after]
    lines += [_flaser(p, 2.0 + k) for k, p in enumerate(poses[1:])]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_declared_front_laser_offset_places_scans_and_poses_at_the_robots_centre(tmp_path):
    path = _log(
        tmp_path / "a.log",
        [
            "robot_frontlaser_offset 0.0",
            "robot_frontlaser_offset -0.2",
            "robot_frontlaser_side_offset 0.05",
            "robot_frontlaser_angular_offset 0.1",
        ],
    )
    log = open_log(path)
    assert log.mount is not None
    assert (log.mount.x, log.mount.y, log.mount.yaw) == (-0.2, 0.05, 0.1)
    assert "PARAM robot_frontlaser_offset -0.2 (line 2)" in (log.mount_source or "")
    # The pose fields are the laser's: the robot's centre is pose ∘ mount⁻¹.
    laser = np.array([0.5, 0.1, 0.3])
    assert np.allclose(log.scans[1].odometry, se2.compose(laser, se2.inverse([-0.2, 0.05, 0.1])))
    # A point straight ahead of the laser lies 0.2 m less far ahead of the centre, turned.
    start, step = flaser_angles(181)
    ahead = round(-start / step)
    point = log.scans[0].points()[ahead]
    assert np.allclose(point, se2.transform_points([-0.2, 0.05, 0.1], [[2.0, 0.0]])[0])


def test_laser_pose_wins_and_a_log_at_the_base_says_where_it_read_so(tmp_path, capsys):
    path = _log(tmp_path / "a.log", ["robot_frontlaser_offset -0.2"])
    given = open_log(path, ReadOptions(laser_pose=(0.0, 0.0, 0.0)))
    assert given.mount is not None and given.mount.is_base
    assert "given by --laser-pose" in (given.mount_source or "")
    at_base = open_log(_log(tmp_path / "b.log", ["robot_frontlaser_offset 0.0"]))
    assert at_base.mount is None
    cmd.main(["info", str(tmp_path / "b.log")])
    said = capsys.readouterr().out
    assert "at the base (declared in the log: PARAM robot_frontlaser_offset 0 (line 1))" in said


def test_a_value_declared_after_the_first_scan_is_not_the_logs(tmp_path):
    log = open_log(_log(tmp_path / "a.log", [], after=("robot_frontlaser_offset -0.2",)))
    assert log.mount is None


def test_a_rear_laser_reads_the_rear_offset(tmp_path):
    path = tmp_path / "r.log"
    ranges = " ".join(["2.0"] * 181)
    path.write_text(
        "PARAM robot_frontlaser_offset 0.3 nohost 0\nPARAM robot_rearlaser_offset -0.25 nohost 0\n"
        + "".join(f"RLASER 181 {ranges} {k} 0 0 {k} 0 0 {k + 1.0} h {k + 1.0}\n" for k in range(3))
    )
    log = open_log(path, ReadOptions(laser="rear"))
    assert log.mount is not None and log.mount.x == -0.25


def test_a_bad_offset_names_its_line(tmp_path):
    path = _log(tmp_path / "a.log", ["robot_frontlaser_offset nope"])
    with pytest.raises(InputError, match=r"a\.log:1: PARAM: field 2 'nope' is not a number"):
        open_log(path)
