"""Joining a log to a reference log by timestamp: one-to-one, or an error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vgm_studio.datasets import open_log
from vgm_studio.datasets.reference import with_reference
from vgm_studio.errors import InputError


def flaser(ranges, pose, t):
    vals = " ".join(f"{r:.2f}" for r in ranges)
    p = " ".join(str(v) for v in (*pose, *pose))
    return f"FLASER {len(ranges)} {vals} {p} {t} host {t}"


def write(tmp_path: Path, name: str, lines: list[str]) -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def scan_ranges(k: int) -> list[float]:
    return [1.0 + 0.1 * k + 0.01 * i for i in range(5)]


def test_repeated_reference_timestamps_are_refused(tmp_path):
    # The infinite-corridor case: many scans share one timestamp.
    lines = [flaser(scan_ranges(k), (k, 0, 0), 7.0) for k in range(4)]
    ref = write(tmp_path, "ref-corrected.log", lines)
    log = open_log(ref)
    with pytest.raises(InputError, match=r"timestamps repeat.*ambiguous") as exc:
        with_reference(log, log)
    assert exc.value.path == str(ref)


def test_several_scans_near_one_pose_without_same_ranges_are_refused(tmp_path):
    raw = write(
        tmp_path, "raw.log", [flaser(scan_ranges(k), (0, 0, 0), 10 + 0.01 * k) for k in range(3)]
    )
    # Different ranges from every raw scan, so only the clock could decide, and it cannot.
    ref = write(tmp_path, "ref-corrected.log", [flaser(scan_ranges(50), (1, 2, 0), 10.01)])
    with pytest.raises(InputError, match=r"several scans .* ambiguous"):
        with_reference(open_log(raw), open_log(ref), tolerance=0.05)


def test_identical_ranges_pick_the_scan_in_a_burst_and_offset_shifts_the_clock(tmp_path):
    # A burst of raw scans 2 ms apart; the reference (relative clock) holds scan 2's ranges.
    raw = write(
        tmp_path,
        "raw.log",
        [flaser(scan_ranges(k), (0, 0, 0), 1000 + 0.002 * k) for k in range(5)],
    )
    ref = write(tmp_path, "ref-corrected.log", [flaser(scan_ranges(2), (4, 5, 0.5), 0.003)])
    joined = with_reference(open_log(raw), open_log(ref), tolerance=0.05, time_offset=1000.0)
    got = [s.reference is not None for s in joined.scans]
    assert got == [False, False, True, False, False]
    np.testing.assert_allclose(joined.scans[2].reference, [4, 5, 0.5])
    with pytest.raises(InputError, match="no scan timestamp matches"):
        with_reference(open_log(raw), open_log(ref), tolerance=0.05)


@pytest.mark.parametrize(("tolerance", "offset"), [(0.0, 0.0), (11.0, 0.0), (0.05, np.inf)])
def test_bad_tolerance_or_offset_is_a_caller_bug(tmp_path, tolerance, offset):
    log = open_log(write(tmp_path, "a-corrected.log", [flaser(scan_ranges(0), (0, 0, 0), 1)]))
    with pytest.raises(ValueError):
        with_reference(log, log, tolerance=tolerance, time_offset=offset)


def test_intel_raw_log_joins_the_gmapping_log_with_the_offset(datasets):
    raw = open_log(datasets / "intel" / "intel.clf")
    ref = open_log(datasets / "intel" / "intel.gfs.log")
    joined = with_reference(raw, ref, 0.05, 976052857.33753)
    # Every GMapping scan is one of intel.clf's (same ranges, within 6 ms).
    assert sum(s.reference is not None for s in joined.scans) == len(ref) == 910
