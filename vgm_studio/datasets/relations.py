"""Freiburg benchmark relations files (Kümmerle et al. 2009).

Each line is ``timestamp1 timestamp2 x y z roll pitch yaw``: the pose of the scan taken at
timestamp2 in the frame of the scan taken at timestamp1. Timestamps are the scans' ipc stamps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vgm_studio.errors import InputError

_FIELDS = ("t1", "t2", "x", "y", "z", "roll", "pitch", "yaw")


@dataclass(frozen=True)
class Relation:
    """One relation: scan b (at ``t_b``) in the frame of scan a (at ``t_a``), as (x, y, θ)."""

    line: int
    t_a: float
    t_b: float
    pose: NDArray[np.float64]


@dataclass(frozen=True)
class MatchedRelation:
    """A relation tied to scan indices of a log."""

    a: int
    b: int
    pose: NDArray[np.float64]
    line: int


def read_relations(path: str | Path) -> list[Relation]:
    """Reads a relations file; a malformed line raises ``InputError`` with its line number."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "no such file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            path, f"not a text relations file ({exc.reason} at byte {exc.start})"
        ) from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or type(exc).__name__})") from None
    out = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        out.append(_parse_line(path, lineno, tokens))
    if not out:
        raise InputError(path, "holds no relations")
    return out


def _parse_line(path: Path, lineno: int, tokens: list[str]) -> Relation:
    if len(tokens) != 8:
        raise InputError(
            path,
            f"expected 8 fields (t1 t2 x y z roll pitch yaw), found {len(tokens)}",
            line=lineno,
        )
    try:
        v = [float(t) for t in tokens]
    except ValueError:
        raise InputError(path, "every field must be a number", line=lineno) from None
    bad = [_FIELDS[i] for i, x in enumerate(v) if not math.isfinite(x)]
    if bad:
        raise InputError(path, f"{', '.join(bad)}: not a finite number", line=lineno)
    return Relation(lineno, v[0], v[1], np.array([v[2], v[3], v[7]]))


def looks_like_relations(path: Path) -> bool:
    """True when the first data line has the eight numeric fields of a relations file."""
    if path.suffix == ".relations":
        return True
    try:
        with path.open(encoding="utf-8") as f:
            for text in f:
                tokens = text.split()
                if tokens and not tokens[0].startswith("#"):
                    return len(tokens) == 8 and all(_is_number(t) for t in tokens)
    except (OSError, UnicodeDecodeError):
        return False
    return False


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def match_relations(
    relations: list[Relation], timestamps: NDArray[np.float64], tolerance: float = 1e-3
) -> tuple[list[MatchedRelation], int]:
    """Ties relations to scan indices by nearest timestamp within ``tolerance`` seconds.

    Returns:
        The matched relations and how many relations found no scan.
    """
    order = np.argsort(timestamps)
    sorted_t = timestamps[order]

    def nearest(t: float) -> int | None:
        k = int(np.searchsorted(sorted_t, t))
        best = None
        for j in (k - 1, k):
            if (
                0 <= j < len(sorted_t)
                and abs(sorted_t[j] - t) <= tolerance
                and (best is None or abs(sorted_t[j] - t) < abs(sorted_t[best] - t))
            ):
                best = j
        return None if best is None else int(order[best])

    matched, missed = [], 0
    for r in relations:
        a, b = nearest(r.t_a), nearest(r.t_b)
        if a is None or b is None or a == b:
            missed += 1
            continue
        matched.append(MatchedRelation(a, b, r.pose, r.line))
    return matched, missed
