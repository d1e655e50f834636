"""CARMEN reader: message types, beam conventions, pose sources, malformed input."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.datasets import ReadOptions, open_log
from vgm_studio.datasets.carmen import flaser_angles, format_pose_message, format_robotlaser
from vgm_studio.errors import InputError


def flaser(ranges, pose, odom, t):
    vals = " ".join(str(r) for r in ranges)
    p = " ".join(str(v) for v in (*pose, *odom))
    return f"FLASER {len(ranges)} {vals} {p} {t} host {t}"


def write(tmp_path: Path, lines: list[str], name: str = "test.log") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("beams", "first", "last", "step"),
    [
        (180, -90.0, 89.0, 1.0),
        (181, -90.0, 90.0, 1.0),
        (360, -90.0, 89.5, 0.5),
        (361, -90.0, 90.0, 0.5),
    ],
)
def test_flaser_beam_convention(beams, first, last, step):
    start, inc = flaser_angles(beams)
    assert math.degrees(start) == pytest.approx(first)
    assert math.degrees(inc) == pytest.approx(step)
    assert math.degrees(start + inc * (beams - 1)) == pytest.approx(last)


def test_fov_flag_overrides_convention(tmp_path):
    path = write(tmp_path, [flaser([1.0] * 181, (0, 0, 0), (0, 0, 0), 1.0)])
    log = open_log(path, ReadOptions(fov_deg=100.0))
    assert math.degrees(log.scans[0].angle_min) == pytest.approx(-50.0)
    assert math.degrees(log.scans[0].fov) == pytest.approx(100.0)


def test_flaser_points_and_max_range(tmp_path):
    # Beam 0 points right (−90°), beam 90 ahead, beam 180 left; 81.91 is a no-return.
    ranges = [81.91] * 181
    ranges[0], ranges[90], ranges[180] = 2.0, 3.0, 0.0
    path = write(tmp_path, [flaser(ranges, (1, 2, 0.5), (1, 2, 0.5), 10.0)])
    scan = open_log(path).scans[0]
    pts = scan.points()
    assert scan.max_range == pytest.approx(0.95 * 81.91)
    np.testing.assert_allclose(pts, [[0.0, -2.0], [3.0, 0.0]], atol=1e-6)
    explicit = open_log(path, ReadOptions(max_range=2.5)).scans[0]
    np.testing.assert_allclose(explicit.points(), [[0.0, -2.0]], atol=1e-6)


def test_raw_log_has_odometry_in_pose_fields(tmp_path):
    lines = ["# a comment", "PARAM robot_width 0.5 0 h 0", "SYNC x 0 h 0"]
    lines += [flaser([1.0] * 180, (i, 0, 0), (i, 0, 0), float(i)) for i in range(3)]
    log = open_log(write(tmp_path, lines, "run.clf"))
    assert log.pose_source == "odometry"
    assert log.has_odometry and not log.has_reference
    np.testing.assert_allclose(log.odometry_poses()[:, 0], [0, 1, 2])
    assert log.message_counts["PARAM"] == 1 and "PARAM" not in log.ignored_messages


def test_corrected_log_reference_from_flaser_odometry_from_odom(tmp_path):
    lines = []
    for i in range(3):
        lines.append(f"ODOM {i + 0.5} 0 0 0 0 0 {i} host {i}")
        lines.append(flaser([1.0] * 180, (i, 1, 0), (i, 1, 0), float(i)))
        lines.append("NEFF 12.5")
    log = open_log(write(tmp_path, lines, "intel.gfs.log"))
    assert log.pose_source == "reference"
    np.testing.assert_allclose(log.reference_poses()[:, :2], [[0, 1], [1, 1], [2, 1]])
    np.testing.assert_allclose(log.odometry_poses()[:, 0], [0.5, 1.5, 2.5])
    assert log.ignored_messages == {"NEFF": 3}
    forced = open_log(write(tmp_path, lines, "intel.gfs.log"), ReadOptions(poses="odometry"))
    assert forced.pose_source == "odometry" and not forced.has_reference


def test_corrected_log_skips_gmapping_echo_and_takes_the_odom_after_the_scan(tmp_path):
    # GMapping's layout: the scan (corrected pose), its pose again as ODOM, NEFF, then the raw
    # odometry; the raw ODOM right after a scan is its odometry, the echo is none.
    lines = []
    for i in range(3):
        lines.append(flaser([1.0] * 180, (i, 1, 0.1), (i, 1, 0.1), 0.0))
        lines.append(f"ODOM {i} 1 0.1 0 0 0 0 host 0")
        lines.append("NEFF 12.5")
        lines += [f"ODOM {10 * i + 5 + k} 0 0 0 0 0 7 host 7" for k in range(2)]
    # Two scans with only their echoes after them: the first takes the raw ODOM read since the
    # scan before it, the second has none.
    for i in (3, 4):
        lines.append(flaser([1.0] * 180, (i, 1, 0.1), (i, 1, 0.1), 0.0))
        lines.append(f"ODOM {i} 1 0.1 0 0 0 0 host 0")
    log = open_log(write(tmp_path, lines, "b.gfs.log"))
    assert log.pose_source == "reference"
    assert [s.odometry[0] for s in log.scans[:4]] == [5, 15, 25, 26]  # type: ignore[index]
    assert log.scans[4].odometry is None and not log.has_odometry


def test_truepos_gives_reference_interpolated_by_time(tmp_path):
    lines = [
        format_pose_message("TRUEPOS", (0, 0, 0), (0, 0, 0), 0.0),
        format_pose_message("TRUEPOS", (2, 0, 1.0), (0, 0, 0), 2.0),
        format_robotlaser(
            [1.0] * 5,
            angle_min=-1.0,
            angle_increment=0.5,
            max_range=10.0,
            laser_pose=(0.9, 0.1, 0.4),
            timestamp=1.0,
        ),
    ]
    log = open_log(write(tmp_path, lines))
    scan = log.scans[0]
    np.testing.assert_allclose(scan.reference, [1.0, 0.0, 0.5], atol=1e-9)
    np.testing.assert_allclose(scan.odometry, [0.9, 0.1, 0.4], atol=1e-6)
    assert scan.angle_min == pytest.approx(-1.0) and scan.angle_increment == pytest.approx(0.5)
    assert scan.max_range == pytest.approx(10.0)
    assert log.pose_source == "odometry" and log.reference_origin == "TRUEPOS"


def test_robotlaser_with_remissions(tmp_path):
    line = (
        "ROBOTLASER1 0 -1.570796 3.141593 0.785398 81.9 0.01 0 5 1 2 81.9 3 4 2 0.5 0.6 "
        "1 2 0.3 1 2 0.3 0 0 0 0 0 12.5 host 12.5"
    )
    log = open_log(write(tmp_path, [line]))
    scan = log.scans[0]
    assert scan.num_beams == 5 and scan.timestamp == 12.5
    assert len(scan.points()) == 4
    np.testing.assert_allclose(scan.odometry, [1, 2, 0.3])


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("FLASER 180 1 2 3", "expected at least 188 fields"),
        ("FLASER abc 1 2", "is not a beam count"),
        ("FLASER 3 1 2 x 0 0 0 0 0 0 1 h 1", "'x' is not a number"),
        ("ODOM 1 2", "expected at least 4 fields"),
        ("ROBOTLASER1 0 -1.5 3.1 0.01", "expected at least 9 fields"),
    ],
)
def test_malformed_line_names_file_and_line(tmp_path, line, message):
    good = flaser([1.0] * 3, (0, 0, 0), (0, 0, 0), 0.0)
    path = write(tmp_path, [good, "# comment", line, good])
    with pytest.raises(InputError) as err:
        open_log(path)
    text = str(err.value)
    assert text.startswith(f"{path}:3: ")
    assert message in text
    skipped = open_log(path, ReadOptions(skip_bad_lines=True))
    assert skipped.skipped_lines == 1 and len(skipped.scans) == 2


def test_missing_binary_and_empty_logs(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        open_log(tmp_path / "nope.log")
    binary = tmp_path / "bin.log"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    with pytest.raises(InputError, match="not a text log"):
        open_log(binary)
    empty = write(tmp_path, ["# nothing", "ODOM 0 0 0 0 0 0 0 h 0"])
    with pytest.raises(InputError, match="no FLASER/ROBOTLASER1 scans"):
        open_log(empty)


EXPECTED = {
    "intel/intel.clf": (13631, "odometry", False),
    "intel/intel.gfs.log": (910, "reference", True),
    "mit-csail/mit-csail.clf": (1988, "odometry", False),
    "fr-clinic/fr-clinic_robotlaser.clf": (6917, "odometry", False),
    "radish-corrected/infinite-corridor-corrected.log": (1941, "reference", True),
    "radish-corrected/freiburg-campus-corrected.log": (2008, "reference", True),
}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_real_logs(datasets, name):
    count, source, has_reference = EXPECTED[name]
    log = open_log(datasets / name)
    assert len(log) == count
    assert log.pose_source == source
    assert log.has_reference == has_reference
    assert log.has_odometry
    pts = log.scans[len(log) // 2].points()
    assert len(pts) > 50
    # No-returns are dropped: every point is nearer than the sensor's saturation value.
    assert np.hypot(pts[:, 0], pts[:, 1]).max() < log.scans[0].max_range
    assert log.travelled_distance() > 100


def test_every_shared_log_reads(datasets):
    logs = [p for p in sorted(datasets.rglob("*")) if p.suffix in {".clf", ".log"}]
    assert len(logs) >= 13
    for path in logs:
        log = open_log(path)
        assert len(log) > 100, path
        assert log.skipped_lines == 0, path


@pytest.mark.parametrize("bad", ["inf", "nan", "-1", "-inf"])
@pytest.mark.parametrize("kind", ["FLASER", "ROBOTLASER1"])
def test_non_finite_or_negative_ranges_name_the_line(tmp_path, bad, kind):
    if kind == "FLASER":
        line = f"FLASER 3 1 {bad} 1 0 0 0 0 0 0 5 h 5"
    else:
        line = format_robotlaser(
            [1.0, 2.0, 3.0],
            angle_min=-1,
            angle_increment=1,
            max_range=30,
            laser_pose=(0, 0, 0),
            timestamp=5.0,
        ).replace(" 2.000 ", f" {bad} ", 1)
    good = flaser([1, 1, 1], (0, 0, 0), (0, 0, 0), 6)
    path = write(tmp_path, [good, line, good])
    with pytest.raises(InputError, match=rf"test.log:2: {kind}: range 2 .*finite distance") as exc:
        open_log(path)
    assert exc.value.line == 2
    skipped = open_log(path, ReadOptions(skip_bad_lines=True))
    assert len(skipped.scans) == 2 and skipped.skipped_line_numbers == [2]


def test_points_are_kept_only_where_asked():
    """Keyframes keep their points (SLAM asks for them again and again); other scans make them
    anew each time, so a long log does not hold five times its ranges in points."""
    import copy
    import dataclasses
    import pickle

    from vgm_studio.datasets.scans import Scan

    scan = Scan(0, 0.0, np.array([1.0, 2.0, 3.0], np.float32), 0.0, 0.1, 30.0)
    assert scan.points() is not scan.points()
    assert scan.points().flags.writeable
    kept = dataclasses.replace(scan, keep_points=True)
    assert kept.points() is kept.points()
    assert not kept.points().flags.writeable
    np.testing.assert_array_equal(kept.points(), scan.points())
    for other in (pickle.loads(pickle.dumps(kept)), copy.deepcopy(kept), dataclasses.replace(kept)):
        assert not other._points
        np.testing.assert_array_equal(other.points(), scan.points())
