"""What a log holds, as a table a person reads and a dict a script reads."""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from vgm_studio.datasets.scans import ScanLog, mount_line


def summarize(log: ScanLog) -> dict[str, Any]:
    """Counts, beams, field of view, duration, poses present and distance travelled."""
    beams = Counter(s.num_beams for s in log.scans)
    fovs = Counter(
        f"{math.degrees(s.angle_min):+g}° … {math.degrees(s.angle_min + s.fov):+g}° "
        f"in {math.degrees(s.angle_increment):.3g}° steps"
        for s in log.scans
    )
    duration, duration_note = log_duration(log.timestamps)
    points = [len(s.points()) for s in log.scans[:: max(1, len(log.scans) // 200)]]
    return {
        "path": str(log.path),
        "format": log.format,
        "sha256": log.content_hash,
        "scans": len(log.scans),
        "beams": dict(sorted(beams.items())),
        "beam_angles": dict(sorted(fovs.items())),
        "max_range": sorted({round(s.max_range, 3) for s in log.scans}),
        "mean_points_per_scan": float(np.mean(points)) if points else 0.0,
        "duration_s": duration,
        "duration_note": duration_note,
        "odometry": log.has_odometry,
        "odometry_scans": sum(s.odometry is not None for s in log.scans),
        "reference": log.has_reference,
        "reference_origin": log.reference_origin,
        "pose_fields": log.pose_source,
        "travelled_m": log.travelled_distance() if log.has_odometry or log.has_reference else None,
        "mount": None if log.mount is None else log.mount.to_json(),
        "mount_line": mount_line(log),
        "skipped_lines": log.skipped_lines,
        "ignored_messages": log.ignored_messages,
    }


# A log whose clock steps back or stands still this often is not telling time: GMapping
# output printed with too few digits repeats stamps; intel.clf's bursts step back 5% of the time.
MAX_NON_INCREASING = 0.1
# A gap longer than this between two scans is a clock jump (infinite-corridor's stamps wrap
# at 2³²), not a pause in the run.
MAX_GAP_S = 3600.0


def log_duration(stamps: np.ndarray) -> tuple[float | None, str | None]:
    """The time from the first scan to the last, when the timestamps can be believed.

    Returns:
        (seconds, None), or (None, why not) when scans lack a clock, timestamps repeat or step
        back too often, or jump by more than ``MAX_GAP_S``.
    """
    if len(stamps) < 2 or not np.all(np.isfinite(stamps)):
        return None, "no clock"
    steps = np.diff(stamps)
    if np.mean(steps <= 0) > MAX_NON_INCREASING or np.max(np.abs(steps)) > MAX_GAP_S:
        return None, "timestamps repeat or jump"
    return float(stamps.max() - stamps.min()), None


def _counts(d: dict[Any, int], unit: str = "") -> str:
    return ", ".join(f"{k}{unit} ({v} scans)" if len(d) > 1 else f"{k}{unit}" for k, v in d.items())


def format_summary(s: dict[str, Any]) -> str:
    """Renders ``summarize``'s dict as aligned lines."""
    duration = s["duration_s"]
    dur = (
        f"{duration:.1f} s ({duration / 60:.1f} min)"
        if duration is not None
        else f"unknown ({s.get('duration_note') or 'no clock'})"
    )
    pose_note = {
        "reference": "reference (corrected log)",
        "odometry": "odometry (raw log)",
        None: "none",
    }[s["pose_fields"]]
    rows = [
        ("log", s["path"]),
        ("format", s["format"]),
        ("scans", f"{s['scans']:,}"),
        ("beams", _counts(s["beams"])),
        ("beam angles", _counts(s["beam_angles"])),
        ("max range", ", ".join(f"{r:g} m" for r in s["max_range"])),
        ("points per scan", f"{s['mean_points_per_scan']:.0f} (mean)"),
        ("duration", dur),
        ("odometry", _odometry_text(s)),
        ("reference poses", f"yes ({s['reference_origin']})" if s["reference"] else "no"),
        ("scan pose fields", pose_note),
    ]
    if s["travelled_m"] is not None:
        rows.append(("travelled", f"{s['travelled_m']:.1f} m"))
    rows.append(("laser mount", s["mount_line"]))
    if s["ignored_messages"]:
        rows.append(("ignored", ", ".join(f"{k} ×{v}" for k, v in s["ignored_messages"].items())))
    if s["skipped_lines"]:
        rows.append(("skipped bad lines", str(s["skipped_lines"])))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _odometry_text(s: dict[str, Any]) -> str:
    if s["odometry"]:
        return "yes"
    if s.get("odometry_scans"):
        return f"on {s['odometry_scans']:,} of {s['scans']:,} scans only"
    return "none"
