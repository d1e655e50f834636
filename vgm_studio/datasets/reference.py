"""Reference poses from a second log (a corrected log, or one with TRUEPOS), joined by timestamp."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vgm_studio.datasets.scans import ScanLog
from vgm_studio.errors import InputError

# Scans of a 2D laser come at 1–75 Hz; a tolerance above this joins scans to poses taken
# seconds away, which is a label of a different place, not a reference.
MAX_TOLERANCE = 10.0


def with_reference(
    log: ScanLog, reference: ScanLog, tolerance: float = 0.05, time_offset: float = 0.0
) -> ScanLog:
    """Returns ``log`` whose scans carry the reference pose of the nearest-in-time reference scan.

    Scans with no reference scan within ``tolerance`` seconds get none. The join must be
    one-to-one: a wrong join gives wrong labels with nothing to show for it, so every doubt
    is an error rather than a guess.

    Args:
        log: The log whose scans get reference poses.
        reference: A log with reference poses (corrected, or with TRUEPOS).
        tolerance: Largest time difference of a match, seconds, in (0, ``MAX_TOLERANCE``].
        time_offset: Seconds added to the reference's timestamps before the join (GMapping
            output counts from the start of the log; raw logs use absolute time).

    Raises:
        InputError: The reference log has no reference poses or no usable clock, its
            timestamps repeat where scans join it, several scans join one reference pose,
            or no timestamp matches.
        ValueError: ``tolerance`` or ``time_offset`` is out of range (a caller's bug; the
            command line checks both first).
    """
    if not (math.isfinite(tolerance) and 0.0 < tolerance <= MAX_TOLERANCE):
        raise ValueError(f"tolerance must be in (0, {MAX_TOLERANCE}] s, got {tolerance}")
    if not math.isfinite(time_offset):
        raise ValueError(f"time_offset must be finite, got {time_offset}")
    ref_poses = reference.reference_poses()
    if ref_poses is None:
        raise InputError(
            reference.path,
            "has no reference poses (not a corrected log and no "
            "TRUEPOS); use --poses reference if its scan poses are corrected",
        )
    ref_t = reference.timestamps + time_offset
    if not np.all(np.isfinite(ref_t)):
        raise InputError(reference.path, "has scans without a timestamp; cannot join by time")
    log_t = log.timestamps
    log_order = np.argsort(log_t, kind="stable")
    log_sorted = log_t[log_order]
    # Each reference pose goes to the log scans within the tolerance of its timestamp.
    lo = np.searchsorted(log_sorted, ref_t - tolerance, side="left")
    hi = np.searchsorted(log_sorted, ref_t + tolerance, side="right")
    candidates = [log_order[a:b] for a, b in zip(lo, hi, strict=True)]
    _refuse_repeats(log, reference, ref_t, [len(c) > 0 for c in candidates])
    # Logs whose clocks bunch scans together (intel.clf logs bursts of scans within a few
    # milliseconds) cannot be joined by time alone; where both logs hold the same scans,
    # identical ranges tell which scan a reference pose belongs to.
    same = [
        [int(i) for i in c if _same_ranges(log.scans[i].ranges, reference.scans[j].ranges)]
        for j, c in enumerate(candidates)
    ]
    by_ranges = any(same)
    chosen: dict[int, int] = {}  # log scan -> reference pose
    ambiguous = 0
    for j, cands in enumerate(candidates):
        pick = same[j] if by_ranges else [int(i) for i in cands]
        if not pick or (len(pick) > 1 and not by_ranges):
            ambiguous += len(pick) > 1
            continue
        # Several scans with identical ranges: the robot stood still; take the nearest in time.
        i = min(pick, key=lambda i: abs(log_t[i] - ref_t[j]))
        if i in chosen:
            ambiguous += 1
            continue
        chosen[i] = j
    if ambiguous:
        raise InputError(
            reference.path,
            f"{ambiguous} reference pose(s) have several scans of {log.path} within "
            f"{tolerance:g} s, so the join by timestamp is ambiguous (lower "
            "--time-tolerance, or check --time-offset)",
        )
    if not chosen:
        raise InputError(
            reference.path,
            f"no scan timestamp matches {log.path} within {tolerance:g} s "
            "(do both logs use the same clock? see --time-offset)",
        )
    scans = [
        dataclasses.replace(scan, reference=ref_poses[chosen[i]] if i in chosen else None)
        for i, scan in enumerate(log.scans)
    ]
    return dataclasses.replace(log, scans=scans, reference_origin=str(reference.path))


def _same_ranges(a: np.ndarray, b: np.ndarray) -> bool:
    # Logs print ranges to the centimetre (GMapping output) or the millimetre.
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= 0.011))


def _refuse_repeats(
    log: ScanLog, reference: ScanLog, ref_t: np.ndarray, in_reach: list[bool]
) -> None:
    """Refuses a reference whose poses share a timestamp where the log's scans join it."""
    order = np.argsort(ref_t, kind="stable")
    dup = np.flatnonzero(np.diff(ref_t[order]) == 0)
    clash = [int(order[k]) for k in dup if in_reach[order[k]] or in_reach[order[k + 1]]]
    if clash:
        first = reference.scans[min(clash)]
        raise InputError(
            reference.path,
            f"timestamps repeat ({len(clash) + 1} reference poses share timestamps, first at "
            f"line {first.line}), so the join of {log.path} by timestamp is ambiguous",
        )
