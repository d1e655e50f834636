"""TUM trajectory files: one pose a line, ``timestamp x y z qx qy qz qw``.

The format of the TUM RGB-D benchmark, which evo, rpg_trajectory_evaluation and most SLAM
evaluation scripts read. A 2D pose (x, y, θ) is written with z = 0 and the quaternion of a
turn θ about z (qz = sin θ/2, qw = cos θ/2); read back, θ is the quaternion's yaw, so a 3D
trajectory reads as its projection on the ground plane. Lines starting with ``#`` and blank
lines are comments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.atomic import write_text_atomically
from vgm_studio.errors import InputError

FIELDS = ("timestamp", "x", "y", "z", "qx", "qy", "qz", "qw")
# A quaternion this far from unit length is not a rotation that lost digits to rounding but
# a wrong column or a file of another format.
_UNIT_TOLERANCE = 0.01


@dataclass(frozen=True)
class TumTrajectory:
    """A trajectory read from a TUM file.

    Attributes:
        timestamps: (N,) seconds, strictly increasing.
        poses: (N, 3) x, y and the quaternion's yaw θ in (-π, π].
        lines: (N,) the line of the file each pose came from (1-based), for messages.
    """

    timestamps: NDArray[np.float64]
    poses: NDArray[np.float64]
    lines: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.timestamps)


def write_tum(path: Path, timestamps: NDArray[np.float64], poses: NDArray[np.float64]) -> None:
    """Writes 2D poses as a TUM file, whole or not at all (``atomic.atomic_path``).

    Timestamps are written as Python's shortest exact repr, so a reader that ties poses to
    scans by timestamp finds the very numbers the log holds.

    Args:
        path: The file to write.
        timestamps: (N,) seconds, finite and strictly increasing.
        poses: (N, 3) x, y, θ.

    Raises:
        ValueError: The arrays' shapes disagree, a value is not finite, or the timestamps do
            not increase (what ``read_tum`` would refuse).
        InputError: The file cannot be written.
    """
    times = np.asarray(timestamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    if times.ndim != 1 or poses.shape != (len(times), 3):
        raise ValueError(f"timestamps {times.shape} and poses {poses.shape} must be (N,), (N, 3)")
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(poses))):
        raise ValueError("timestamps and poses must be finite")
    if np.any(np.diff(times) <= 0):
        raise ValueError("timestamps must be strictly increasing")
    half = poses[:, 2] / 2
    # Rounded to the printed digits first, and + 0.0, so that a value that rounds to zero
    # prints as 0, never -0.
    xy = np.round(poses[:, :2], 6) + 0.0
    quaternion = np.round(np.column_stack([np.sin(half), np.cos(half)]), 9) + 0.0
    lines = [f"# {' '.join(FIELDS)}\n"]
    for t, (x, y), (qz, qw) in zip(times, xy, quaternion, strict=True):
        lines.append(f"{float(t)!r} {x:.6f} {y:.6f} 0 0 0 {qz:.9f} {qw:.9f}\n")
    try:
        write_text_atomically(path, "".join(lines))
    except OSError as exc:
        raise InputError(path, f"cannot write ({exc.strerror or exc})") from None


def read_tum(path: Path) -> TumTrajectory:
    """Reads a TUM file's poses as (x, y, yaw).

    Raises:
        InputError: The file is missing, unreadable or empty, or a line is malformed: not 8
            fields, a value that is not a finite number, a quaternion far from unit length,
            or a timestamp not after the one before (``line`` names it).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such file" if not path.exists() else "not a file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or type(exc).__name__})") from None
    rows: list[list[float]] = []
    numbers: list[int] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        row = _parse_line(path, lineno, tokens)
        if rows and row[0] <= rows[-1][0]:
            how = "repeats" if row[0] == rows[-1][0] else "goes back from"
            raise InputError(
                path,
                f"timestamp {row[0]!r} {how} line {numbers[-1]}'s ({rows[-1][0]!r}); "
                "timestamps must increase",
                line=lineno,
            )
        rows.append(row)
        numbers.append(lineno)
    if not rows:
        raise InputError(path, "no poses (every line is blank or a # comment)")
    values = np.array(rows, dtype=np.float64)
    return TumTrajectory(
        timestamps=values[:, 0],
        poses=np.column_stack([values[:, 1], values[:, 2], _yaw(values[:, 4:8])]),
        lines=np.array(numbers, dtype=np.int64),
    )


def _parse_line(path: Path, lineno: int, tokens: list[str]) -> list[float]:
    """One pose line's eight numbers, checked."""
    if len(tokens) != len(FIELDS):
        raise InputError(
            path,
            f"expected {len(FIELDS)} fields ({' '.join(FIELDS)}), found {len(tokens)}",
            line=lineno,
        )
    row = []
    for name, token in zip(FIELDS, tokens, strict=True):
        try:
            value = float(token)
        except ValueError:
            raise InputError(path, f"{name} is not a number: {token!r}", line=lineno) from None
        if not math.isfinite(value):
            raise InputError(path, f"{name} is not finite: {token}", line=lineno)
        row.append(value)
    norm = math.sqrt(sum(v * v for v in row[4:8]))
    if abs(norm - 1.0) > _UNIT_TOLERANCE:
        raise InputError(
            path,
            f"the quaternion (qx qy qz qw) has length {norm:.4g}, not 1: not a rotation",
            line=lineno,
        )
    return row


def _yaw(quaternions: NDArray[np.float64]) -> NDArray[np.float64]:
    """Yaw (rotation about z, ZYX order) of (N, 4) quaternions qx qy qz qw, normalised first."""
    q = quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)
    x, y, z, w = q.T
    return np.asarray(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)), dtype=np.float64)
