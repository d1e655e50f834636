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
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core.hashing import content_hash
from vgm_studio.datasets.options import ReadOptions
from vgm_studio.datasets.scans import PoseSource, Scan, ScanLog
from vgm_studio.errors import InputError

SKIPPED = frozenset({"PARAM", "SYNC"})
_CORRECTED_NAME = re.compile(r"corrected|\.gfs\.", re.IGNORECASE)
# A reading float32 cannot hold would be stored as inf and make the log's range inf.
MAX_READING = float(np.finfo(np.float32).max)
# Fields after the readings: two poses (6) then, optionally, ipc_timestamp host logger_timestamp.
_FLASER_TAILS = (6, 9)
# Poses are metres in a local frame; even UTM northings stay below 1e7 m. Beyond that,
# distances between poses overflow to inf.
MAX_COORDINATE = 1e7
# ROBOTLASER1 after the remissions: two poses, tv rv forward_safety side_safety turn_axis (11),
# then optionally the three timestamp fields.
_ROBOTLASER_TAILS = (11, 14)
_QUOTE_CHARS = 12
_MESSAGE_NAME = re.compile(r"[A-Z][A-Z0-9_]{0,23}")
_UNSAFE = re.compile(r"[^\x21-\x7e]")


def quote_token(token: str) -> str:
    """A log token safe to print: at most a few printable ASCII characters, others as ``?``.

    A message must not echo a hostile file: escape sequences, NUL or a secret read by mistake.
    """
    short = _UNSAFE.sub("?", token[:_QUOTE_CHARS])
    return f"'{short}…'" if len(token) > _QUOTE_CHARS else f"'{short}'"


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


@dataclass
class _RawScan:
    line: int
    timestamp: float
    ranges: NDArray[np.float32]
    angle_min: float | None  # None: FLASER convention, fixed once the log is read
    angle_increment: float | None
    max_range: float | None
    pose: NDArray[np.float64]
    odom_before: NDArray[np.float64] | None


class _LineParser:
    """Splits and converts one message, raising ``InputError`` with the line number."""

    def __init__(self, path: Path, lineno: int, tokens: list[str]) -> None:
        self.path, self.lineno, self.tokens = path, lineno, tokens

    def fail(self, message: str) -> InputError:
        kind = _UNSAFE.sub("?", self.tokens[0][:_QUOTE_CHARS])
        return InputError(self.path, f"{kind}: {message}", line=self.lineno)

    def need(self, count: int, what: str) -> None:
        if len(self.tokens) < count:
            raise self.fail(f"expected at least {count} fields ({what}), found {len(self.tokens)}")

    def exact(self, counts: tuple[int, ...], declared: str) -> None:
        """The line must have one of ``counts`` fields: a wrong count shifts every later field."""
        if len(self.tokens) not in counts:
            expected = " or ".join(map(str, counts))
            raise self.fail(
                f"{declared}, so the line should have {expected} fields, but it has "
                f"{len(self.tokens)}"
            )

    def number(self, i: int) -> float:
        self.need(i + 1, f"field {i}")
        try:
            value = float(self.tokens[i])
        except ValueError:
            raise self.fail(f"field {i} {quote_token(self.tokens[i])} is not a number") from None
        if math.isnan(value):
            raise self.fail(f"field {i} is NaN")
        return value

    def finite(self, i: int, what: str) -> float:
        value = self.number(i)
        if not math.isfinite(value):
            raise self.fail(f"{what} (field {i}) must be a finite number, got {value}")
        return value

    def count(self, i: int) -> int:
        self.need(i + 1, f"the count in field {i}")
        token = self.tokens[i]
        # int() of a 5,000-digit token raises ValueError; a beam count has at most a few digits.
        if len(token) > 9 or not token.isdigit():
            raise self.fail(f"field {i} {quote_token(token)} is not a beam count")
        return int(token)

    def numbers(self, start: int, stop: int) -> NDArray[np.float64]:
        try:
            return np.array(self.tokens[start:stop], dtype=np.float64)
        except ValueError:
            for i in range(start, stop):
                self.number(i)
            raise

    def ranges(self, start: int, stop: int) -> NDArray[np.float32]:
        """The readings ``start:stop``; each must be a finite distance, ≥ 0."""
        values = self.numbers(start, stop)
        bad = np.flatnonzero(~np.isfinite(values) | (values < 0) | (values > MAX_READING))
        if len(bad):
            k = int(bad[0])
            raise self.fail(
                f"range {k + 1} (field {start + k}) is {quote_token(self.tokens[start + k])}; "
                "a reading must be a finite distance ≥ 0 (that a float32 holds)"
                + (f" ({len(bad)} such readings)" if len(bad) > 1 else "")
            )
        return values.astype(np.float32)

    def pose(self, start: int) -> NDArray[np.float64]:
        pose = np.array([self.number(start + k) for k in range(3)])
        if not np.all(np.isfinite(pose)):
            raise self.fail(f"pose (fields {start}..{start + 2}) is not finite")
        if np.max(np.abs(pose[:2])) > MAX_COORDINATE:
            raise self.fail(
                f"pose (fields {start}..{start + 1}) is over {MAX_COORDINATE:g} m from the origin"
            )
        return pose

    def timestamp(self, i: int) -> float:
        return self.finite(i, "timestamp") if i < len(self.tokens) else float("nan")


def _parse_flaser(p: _LineParser) -> _RawScan:
    n = p.count(1)
    p.need(2 + n + 6, f"{n} ranges and two poses")
    p.exact(tuple(2 + n + t for t in _FLASER_TAILS), f"it declares {n} readings")
    return _RawScan(
        line=p.lineno,
        timestamp=p.timestamp(2 + n + 6),
        ranges=p.ranges(2, 2 + n),
        angle_min=None,
        angle_increment=None,
        max_range=None,
        pose=p.pose(2 + n),
        odom_before=None,
    )


def _parse_robotlaser(p: _LineParser) -> _RawScan:
    p.need(9, "laser configuration")
    start, _fov, res, max_range = (
        p.finite(i, what)
        for i, what in ((2, "start angle"), (3, "field of view"), (4, "resolution"), (5, "range"))
    )
    if not max_range > 0:
        raise p.fail(f"maximum range (field 5) must be a positive distance, got {max_range}")
    n = p.count(8)
    p.need(9 + n + 1, f"{n} ranges and the remission count")
    m = p.count(9 + n)
    tail = 9 + n + 1 + m
    p.need(tail + 6, "laser and robot poses")
    p.exact(
        tuple(tail + t for t in _ROBOTLASER_TAILS), f"it declares {n} readings and {m} remissions"
    )
    return _RawScan(
        line=p.lineno,
        timestamp=p.timestamp(tail + 11),
        ranges=p.ranges(9, 9 + n),
        angle_min=start,
        angle_increment=res,
        max_range=max_range,
        pose=p.pose(tail),
        odom_before=None,
    )


def _found_messages(counts: Counter[str]) -> str:
    """What a log without scans holds, naming only what looks like a CARMEN message type.

    A file that is not a log at all (a path typed wrong, a secret) is not quoted back.
    """
    named = [(k, v) for k, v in counts.most_common() if _MESSAGE_NAME.fullmatch(k)]
    other = sum(counts.values()) - sum(v for _, v in named)
    parts = [f"{k} ×{v}" for k, v in named[:5]] + (
        [f"{other} other line{'s' if other > 1 else ''}"] if other else []
    )
    return ", ".join(parts) or "nothing"


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
    raw: list[_RawScan] = []
    truepos: list[tuple[float, NDArray[np.float64]]] = []
    last_odom: NDArray[np.float64] | None = None
    bad: list[int] = []
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
        if kind in SKIPPED:
            continue
        p = _LineParser(path, lineno, tokens)
        try:
            if kind == scan_type or (kind == "ROBOTLASER1" and options.laser == "front"):
                scan = _parse_flaser(p) if kind != "ROBOTLASER1" else _parse_robotlaser(p)
                scan.odom_before = last_odom
                raw.append(scan)
            elif kind == "ODOM":
                p.need(4, "a pose")
                last_odom = p.pose(1)
            elif kind == "TRUEPOS":
                p.need(7, "true pose, odometry pose and timestamp")
                truepos.append((p.timestamp(7), p.pose(1)))
            else:
                ignored[kind if _MESSAGE_NAME.fullmatch(kind) else "(not a message)"] += 1
        except InputError:
            if not options.skip_bad_lines:
                raise
            bad.append(lineno)
    if not raw:
        found = _found_messages(counts)
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
            odometry, reference = r.odom_before, r.pose
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
) -> str:
    """Formats one ROBOTLASER1 line (robot pose = laser pose, no remissions)."""
    n = len(ranges)
    fov = angle_increment * max(n - 1, 0)
    x, y, t = laser_pose
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
        *(f"{v:.6f}" for v in (x, y, t, x, y, t)),
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
