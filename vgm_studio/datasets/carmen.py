"""CARMEN logs (``.clf``, ``.log``): FLASER, RLASER, ROBOTLASER1, ODOM and TRUEPOS messages.

Line formats (one message per line, trailing ``ipc_timestamp host logger_timestamp``)::

    FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp
    ROBOTLASER1 type start_angle fov res max_range accuracy remission_mode n r1..rn
                m [remissions] laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety side_safety turn_axis ipc_timestamp host logger_timestamp
    ODOM x y theta tv rv accel ipc_timestamp host logger_timestamp
    TRUEPOS x y theta odom_x odom_y odom_theta ipc_timestamp host logger_timestamp

Comments (``#``), ``PARAM`` and ``SYNC`` are skipped; other message types (``NEFF``, ``RAWLASER1``,
…) are counted and ignored.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core.hashing import content_hash
from vgm_studio.datasets.carmen_lines import (
    MESSAGE_NAME,
    LineParser,
    RawScan,
    found_messages,
    parse_flaser,
    parse_robotlaser,
)
from vgm_studio.datasets.carmen_mount import MOUNT_PARAMS, DeclaredMount
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.scans import PoseSource, Scan, ScanLog
from vgm_studio.errors import InputError

SKIPPED = frozenset({"PARAM", "SYNC"})
_CORRECTED_NAME = re.compile(r"corrected|\.gfs\.", re.IGNORECASE)


def flaser_angles(num_beams: int, fov_deg: float = 180.0) -> tuple[float, float]:
    """Returns (angle_min, angle_increment) in radians for a FLASER scan of ``num_beams``.

    FLASER carries no angles. We follow CARMEN's own ``carmen_laser_guess_fov``: the first beam
    points at −fov/2 (right of ahead, counter-clockwise positive). An odd beam count spans the
    field of view end to end; an even one is the odd scan with its last beam dropped:

    ====== ======================= =========
    beams  angles (fov = 180°)     increment
    ====== ======================= =========
    180    −90°, −89°, …, +89°     1°
    181    −90°, −89°, …, +90°     1°
    360    −90°, −89.5°, …, +89.5° 0.5°
    361    −90°, −89.5°, …, +90°   0.5°
    ====== ======================= =========
    """
    fov = math.radians(fov_deg)
    steps = num_beams - 1 if num_beams % 2 == 1 else num_beams
    return -fov / 2.0, fov / max(steps, 1)


def _guess_pose_source(path: Path, counts: Counter[str]) -> PoseSource:
    if counts.get("TRUEPOS"):
        return "odometry"
    if counts.get("NEFF") or _CORRECTED_NAME.search(path.name):
        return "reference"
    return "odometry"


def _interpolate_poses(
    times: NDArray[np.float64], stamps: NDArray[np.float64], poses: NDArray[np.float64]
) -> NDArray[np.float64]:
    theta = np.unwrap(poses[:, 2])
    out = np.stack(
        [
            np.interp(times, stamps, poses[:, 0]),
            np.interp(times, stamps, poses[:, 1]),
            np.interp(times, stamps, theta),
        ],
        axis=1,
    )
    out[:, 2] = np.pi - np.mod(np.pi - out[:, 2], 2 * np.pi)
    return out


def _echoes(scan_pose: NDArray[np.float64], odom: NDArray[np.float64]) -> bool:
    # GMapping writes each scan's corrected pose again as an ODOM line after it; that line is
    # the reference, not odometry (equal to the pose fields to the printed digits).
    d = odom - scan_pose
    return bool(math.hypot(d[0], d[1]) < 1e-3 and abs(math.remainder(d[2], math.tau)) < 1e-3)


def _corrected_log_odometry(r: RawScan) -> NDArray[np.float64] | None:
    """The raw odometry of a scan in a corrected log, or None if it has none.

    Where GMapping echoed the scan's pose as an ODOM line, the log is in its writer's layout
    (scan, echo, NEFF, then raw ODOM lines) with no usable timestamps, and the first raw ODOM
    after the scan is its odometry: it agrees with the corrected motion 2-5x better than the
    last one before it (median step error on the radish-corrected logs, e.g. freiburg-campus
    0.017 against 0.067 m, csail 0.070 against 0.161 m). An echoed scan with no raw ODOM after
    it takes a raw ODOM read since the scan before it, or has none (orebro's ODOM lines are
    nearly all echoes) rather than an echoed or stale pose.
    """
    if not r.echoed:
        return r.odom_before
    if r.odom_after is not None:
        return r.odom_after
    return r.odom_before if r.fresh_odom else None


def read_carmen(path: str | Path, options: ReadOptions | None = None) -> ScanLog:
    """Reads a CARMEN log.

    Args:
        path: The log file.
        options: How to read it; see ``ReadOptions``.

    Returns:
        The scans in file order, with odometry and reference poses where the log has them.

    Raises:
        InputError: The file is missing or unreadable, a line is malformed (unless
            ``options.skip_bad_lines``), or the log holds no scans.
    """
    path = Path(path)
    options = options or ReadOptions()
    if not path.is_file():
        raise InputError(path, "no such file" if not path.exists() else "not a file")
    scan_type = "FLASER" if options.laser == "front" else "RLASER"
    counts: Counter[str] = Counter()
    ignored: Counter[str] = Counter()
    raw: list[RawScan] = []
    truepos: list[tuple[float, NDArray[np.float64]]] = []
    last_odom: NDArray[np.float64] | None = None
    fresh = False
    bad: list[int] = []
    declared = DeclaredMount()
    try:
        lines: Iterable[str] = path.open("r", encoding="utf-8", errors="strict").readlines()
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not a text log ({exc.reason} at byte {exc.start})") from None
    for lineno, text in enumerate(lines, start=1):
        tokens = text.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        kind = tokens[0]
        counts[kind] += 1
        if kind == "PARAM" and not raw and len(tokens) > 1 and tokens[1] in MOUNT_PARAMS:
            try:
                declared.take(LineParser(path, lineno, tokens))
            except InputError:
                if not options.skip_bad_lines:
                    raise
                bad.append(lineno)
            continue
        if kind in SKIPPED:
            continue
        p = LineParser(path, lineno, tokens)
        try:
            if kind == scan_type or (kind == "ROBOTLASER1" and options.laser == "front"):
                scan = parse_flaser(p) if kind != "ROBOTLASER1" else parse_robotlaser(p)
                scan.odom_before, scan.fresh_odom = last_odom, fresh
                raw.append(scan)
                fresh = False
            elif kind == "ODOM":
                p.need(4, "a pose")
                pose = p.pose(1)
                if raw and _echoes(raw[-1].pose, pose):
                    raw[-1].echoed = True
                else:
                    if raw and raw[-1].odom_after is None:
                        raw[-1].odom_after = pose
                    last_odom, fresh = pose, True
            elif kind == "TRUEPOS":
                p.need(7, "true pose, odometry pose and timestamp")
                truepos.append((p.timestamp(7), p.pose(1)))
            else:
                ignored[kind if MESSAGE_NAME.fullmatch(kind) else "(not a message)"] += 1
        except InputError:
            if not options.skip_bad_lines:
                raise
            bad.append(lineno)
    if not raw:
        found = found_messages(counts)
        raise InputError(path, f"no {scan_type}/ROBOTLASER1 scans in this log (found {found})")

    source: PoseSource = (
        _guess_pose_source(path, counts) if options.poses == "auto" else options.poses
    )
    max_flaser = max(
        (float(r.ranges.max(initial=0.0)) for r in raw if r.max_range is None), default=0.0
    )
    flaser_max = options.max_range or 0.95 * max_flaser
    reference_from_truepos: NDArray[np.float64] | None = None
    if truepos:
        stamps = np.array([t for t, _ in truepos])
        poses = np.array([q for _, q in truepos])
        times = np.array([r.timestamp for r in raw])
        if np.all(np.isfinite(stamps)) and np.all(np.diff(stamps) >= 0):
            reference_from_truepos = _interpolate_poses(times, stamps, poses)

    scans: list[Scan] = []
    rear = options.laser == "rear"
    for i, r in enumerate(raw):
        if r.angle_min is None or r.angle_increment is None:
            angle_min, inc = flaser_angles(len(r.ranges), options.fov_deg)
            if rear:
                angle_min += math.pi
        else:
            angle_min, inc = r.angle_min, r.angle_increment
        max_range = options.max_range or (r.max_range if r.max_range is not None else flaser_max)
        odometry: NDArray[np.float64] | None
        if reference_from_truepos is not None:
            odometry, reference = r.pose, reference_from_truepos[i]
        elif source == "reference":
            odometry, reference = _corrected_log_odometry(r), r.pose
        else:
            odometry, reference = r.pose, None
        scans.append(
            Scan(
                index=i,
                timestamp=r.timestamp,
                ranges=r.ranges,
                angle_min=angle_min,
                angle_increment=inc,
                max_range=float(max_range),
                odometry=odometry,
                reference=reference,
                line=r.line,
            )
        )
    return ScanLog(
        path=path,
        format="carmen",
        scans=scans,
        content_hash=content_hash(path),
        pose_source=source,
        reference_origin=(
            "TRUEPOS"
            if reference_from_truepos is not None
            else "pose fields"
            if source == "reference"
            else None
        ),
        skipped_lines=len(bad),
        skipped_line_numbers=bad,
        ignored_messages=dict(ignored),
        message_counts=dict(counts),
        declared_mount=declared.mount(options.laser),
    )


def format_robotlaser(
    ranges: Sequence[float] | NDArray[np.floating],
    *,
    angle_min: float,
    angle_increment: float,
    max_range: float,
    laser_pose: Sequence[float] | NDArray[np.floating],
    timestamp: float,
    host: str = "vgm-studio",
    robot_pose: Sequence[float] | NDArray[np.floating] | None = None,
) -> str:
    """Formats one ROBOTLASER1 line (no remissions); the robot's pose is the laser's unless
    given."""
    n = len(ranges)
    fov = angle_increment * max(n - 1, 0)
    x, y, t = laser_pose
    rx, ry, rt = laser_pose if robot_pose is None else robot_pose
    fields = [
        "ROBOTLASER1",
        "0",
        f"{angle_min:.9f}",
        f"{fov:.9f}",
        f"{angle_increment:.9f}",
        f"{max_range:.3f}",
        "0.010",
        "0",
        str(n),
        *(f"{r:.3f}" for r in ranges),
        "0",
        *(f"{v:.6f}" for v in (x, y, t, rx, ry, rt)),
        "0",
        "0",
        "0",
        "0",
        "0",
        f"{timestamp:.6f}",
        host,
        f"{timestamp:.6f}",
    ]
    return " ".join(fields)


def format_pose_message(
    kind: str,
    pose: Sequence[float] | NDArray[np.floating],
    odom: Sequence[float] | NDArray[np.floating],
    timestamp: float,
    host: str = "vgm-studio",
) -> str:
    """Formats an ODOM line (``odom`` = tv rv accel) or a TRUEPOS line (``odom`` = odometry)."""
    values = " ".join(f"{v:.6f}" for v in (*pose, *odom))
    return f"{kind} {values} {timestamp:.6f} {host} {timestamp:.6f}"
