"""One CARMEN line at a time: split, count-checked, converted, with safe messages.

``read_carmen`` hands each scan line to ``parse_flaser`` or ``parse_robotlaser``; every failure
is an ``InputError`` naming the file and line, quoting at most a few sanitised characters of
the token at fault.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.errors import InputError

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
MESSAGE_NAME = re.compile(r"[A-Z][A-Z0-9_]{0,23}")
_UNSAFE = re.compile(r"[^\x21-\x7e]")


def quote_token(token: str) -> str:
    """A log token safe to print: at most a few printable ASCII characters, others as ``?``.

    A message must not echo a hostile file: escape sequences, NUL or a secret read by mistake.
    """
    short = _UNSAFE.sub("?", token[:_QUOTE_CHARS])
    return f"'{short}…'" if len(token) > _QUOTE_CHARS else f"'{short}'"


@dataclass
class RawScan:
    """A scan line as read, before the log-wide FLASER angles and range are known."""

    line: int
    timestamp: float
    ranges: NDArray[np.float32]
    angle_min: float | None  # None: FLASER convention, fixed once the log is read
    angle_increment: float | None
    max_range: float | None
    pose: NDArray[np.float64]
    odom_before: NDArray[np.float64] | None
    # The first ODOM after the scan that is not GMapping's echo of its pose (corrected logs).
    odom_after: NDArray[np.float64] | None = None
    echoed: bool = False  # an ODOM line repeating the scan's pose followed it (GMapping output)
    fresh_odom: bool = False  # odom_before came after the scan before this one
    robot_pose: NDArray[np.float64] | None = None  # ROBOTLASER1's second pose, the robot's


class LineParser:
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
        # Floats, not a numpy array, until checked: a log has three poses a scan (Intel: 40,546).
        x, y, theta = (self.number(start + k) for k in range(3))
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):
            raise self.fail(f"pose (fields {start}..{start + 2}) is not finite")
        if max(abs(x), abs(y)) > MAX_COORDINATE:
            raise self.fail(
                f"pose (fields {start}..{start + 1}) is over {MAX_COORDINATE:g} m from the origin"
            )
        return np.array((x, y, theta))

    def timestamp(self, i: int) -> float:
        return self.finite(i, "timestamp") if i < len(self.tokens) else float("nan")


def parse_flaser(p: LineParser) -> RawScan:
    n = p.count(1)
    p.need(2 + n + 6, f"{n} ranges and two poses")
    p.exact(tuple(2 + n + t for t in _FLASER_TAILS), f"it declares {n} readings")
    return RawScan(
        line=p.lineno,
        timestamp=p.timestamp(2 + n + 6),
        ranges=p.ranges(2, 2 + n),
        angle_min=None,
        angle_increment=None,
        max_range=None,
        pose=p.pose(2 + n),
        odom_before=None,
    )


def parse_robotlaser(p: LineParser) -> RawScan:
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
    return RawScan(
        line=p.lineno,
        timestamp=p.timestamp(tail + 11),
        ranges=p.ranges(9, 9 + n),
        angle_min=start,
        angle_increment=res,
        max_range=max_range,
        pose=p.pose(tail),
        odom_before=None,
        robot_pose=p.pose(tail + 3),
    )


def found_messages(counts: Counter[str]) -> str:
    """What a log without scans holds, naming only what looks like a CARMEN message type.

    A file that is not a log at all (a path typed wrong, a secret) is not quoted back.
    """
    named = [(k, v) for k, v in counts.most_common() if MESSAGE_NAME.fullmatch(k)]
    other = sum(counts.values()) - sum(v for _, v in named)
    parts = [f"{k} ×{v}" for k, v in named[:5]] + (
        [f"{other} other line{'s' if other > 1 else ''}"] if other else []
    )
    return ", ".join(parts) or "nothing"
