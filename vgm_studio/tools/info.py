"""What a log holds, as a table a person reads and a dict a script reads."""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from vgm_studio.datasets.scans import ScanLog


def summarize(log: ScanLog) -> dict[str, Any]:
    """Counts, beams, field of view, duration, poses present and distance travelled."""
    beams = Counter(s.num_beams for s in log.scans)
    fovs = Counter(
        f"{math.degrees(s.angle_min):+g}° … {math.degrees(s.angle_min + s.fov):+g}° "
        f"in {math.degrees(s.angle_increment):.3g}° steps"
        for s in log.scans
    )
    stamps = log.timestamps
    finite = stamps[np.isfinite(stamps)]
    duration = float(finite.max() - finite.min()) if len(finite) > 1 else 0.0
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
        "odometry": log.has_odometry,
        "reference": log.has_reference,
        "reference_origin": log.reference_origin,
        "pose_fields": log.pose_source,
        "travelled_m": log.travelled_distance(),
        "skipped_lines": log.skipped_lines,
        "ignored_messages": log.ignored_messages,
    }


def _counts(d: dict[Any, int], unit: str = "") -> str:
    return ", ".join(f"{k}{unit} ({v} scans)" if len(d) > 1 else f"{k}{unit}" for k, v in d.items())


def format_summary(s: dict[str, Any]) -> str:
    """Renders ``summarize``'s dict as aligned lines."""
    duration = s["duration_s"]
    dur = f"{duration:.1f} s ({duration / 60:.1f} min)" if duration > 0 else "unknown (no clock)"
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
        ("odometry", "yes" if s["odometry"] else "no"),
        ("reference poses", f"yes ({s['reference_origin']})" if s["reference"] else "no"),
        ("scan pose fields", pose_note),
        ("travelled", f"{s['travelled_m']:.1f} m"),
    ]
    if s["ignored_messages"]:
        rows.append(("ignored", ", ".join(f"{k} ×{v}" for k, v in s["ignored_messages"].items())))
    if s["skipped_lines"]:
        rows.append(("skipped bad lines", str(s["skipped_lines"])))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
