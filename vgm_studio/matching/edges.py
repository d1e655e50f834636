"""Candidate edges and their JSONL files: one JSON object per edge, one edge per line."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from vgm_studio.atomic import atomic_path
from vgm_studio.errors import InputError
from vgm_studio.matching.edge_schema import json_lines, load_json_line, parse_edge_row

EdgeKind = Literal["sequential", "loop"]
Label = Literal["success", "failure", "ambiguous"]
KINDS: tuple[str, ...] = ("sequential", "loop")
LABELS: tuple[str, ...] = ("success", "failure", "ambiguous")
PoseList = list[float]


def edge_id(log_sha256: str, a: int, b: int, estimate: Iterable[float], mount: str = "") -> str:
    """A stable id: the same log, scans, laser mount and estimate (to 1e-6) give the same id on
    every run. ``mount`` is ``LaserMount.id_text()``: empty for a laser at the base, so the ids
    of edges made before mounts existed stand."""
    est = ",".join(f"{v:.6f}" for v in estimate)
    text = f"{log_sha256}:{a}:{b}:{est}" + (f":{mount}" if mount else "")
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class Edge:
    """A matched scan pair. Poses are of scan b in the frame of scan a as [x, y, θ], θ in radians.

    Attributes:
        edge_id: Stable id (see ``edge_id``).
        log_path: Path of the log the scans come from.
        log_sha256: Content hash of that log.
        a: Index of the first (previous) scan in the log.
        b: Index of the second (current) scan.
        timestamp_a: Timestamp of scan a.
        timestamp_b: Timestamp of scan b.
        kind: ``sequential`` (consecutive keyframes) or ``loop``.
        guess: The initial guess the matcher started from.
        estimate: The matcher's estimate.
        match: The matcher's figures (iterations, converged, inlier_ratio, residual, covariance).
        reference: The reference relative pose, or None.
        label: ``success``, ``failure``, ``ambiguous`` (from the reference), or None.
        params: How the edge was made: read options, matcher and candidate settings.
    """

    edge_id: str
    log_path: str
    log_sha256: str
    a: int
    b: int
    timestamp_a: float
    timestamp_b: float
    kind: EdgeKind
    guess: PoseList
    estimate: PoseList
    match: dict[str, Any] = field(default_factory=dict)
    reference: PoseList | None = None
    label: Label | None = None
    params: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "edge_id": self.edge_id,
            "log_path": self.log_path,
            "log_sha256": self.log_sha256,
            "a": self.a,
            "b": self.b,
            "timestamp_a": _finite_or_none(self.timestamp_a),
            "timestamp_b": _finite_or_none(self.timestamp_b),
            "kind": self.kind,
            "guess": self.guess,
            "estimate": self.estimate,
            "match": self.match,
            "reference": self.reference,
            "label": self.label,
            "params": self.params,
        }

    @classmethod
    def from_json(cls, obj: Any, path: Path | str | None = None, line: int | None = None) -> Edge:
        """Parses one edge object, raising ``InputError`` that names the file, line and field."""
        row = parse_edge_row(obj, path, line)
        return cls(
            edge_id=row.edge_id,
            log_path=row.log_path,
            log_sha256=row.log_sha256,
            a=row.a,
            b=row.b,
            timestamp_a=_nan_if_none(row.timestamp_a),
            timestamp_b=_nan_if_none(row.timestamp_b),
            kind=row.kind,
            guess=row.guess,
            estimate=row.estimate,
            match=row.match.model_dump(exclude_unset=True),
            reference=row.reference,
            label=row.label,
            params=row.params.model_dump(exclude_unset=True),
        )


def _nan_if_none(value: float | None) -> float:
    return float("nan") if value is None else value


def _finite_or_none(value: float) -> float | None:
    # JSON has no NaN; logs without a clock give scans no timestamp.
    return value if math.isfinite(value) else None


def write_edges(path: str | Path, edges: Iterable[Edge]) -> int:
    """Writes edges as JSONL atomically (a crash never leaves half a file). Returns the count.

    Raises:
        InputError: ``path`` cannot be written (a folder, no permission, a full disk).
    """
    path = Path(path)
    count = 0
    try:
        with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
            for edge in edges:
                f.write(json.dumps(edge.to_json(), separators=(",", ":")) + "\n")
                count += 1
    except OSError as exc:
        raise InputError(path, f"cannot write ({exc.strerror or exc})") from None
    return count


def read_edges(path: str | Path) -> list[Edge]:
    """Reads a JSONL edge file; a malformed line raises ``InputError`` with its line number."""
    return [edge for _, edge in read_edge_rows(path)]


def read_edge_rows(path: str | Path) -> list[tuple[int, Edge]]:
    """Reads a JSONL edge file as (line number, edge) pairs.

    Raises:
        InputError: The file is missing, not UTF-8, empty, or a line breaks the edge schema
            (``file:line: field: what is wrong``).
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(path, "is a folder, not an edges file")
    if not path.is_file():
        raise InputError(path, "no such file")
    try:
        lines = json_lines(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(
            path, f"not a text edges file ({exc.reason} at byte {exc.start})"
        ) from None
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or type(exc).__name__})") from None
    rows = [
        (lineno, Edge.from_json(load_json_line(text, path, lineno), path, lineno))
        for lineno, text in enumerate(lines, start=1)
        if text.strip()
    ]
    if not rows:
        raise InputError(path, "holds no edges")
    return rows
