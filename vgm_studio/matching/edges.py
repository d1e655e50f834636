"""Candidate edges and their JSONL files: one JSON object per edge, one edge per line."""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from vgm_studio.errors import InputError

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
        """Parses one edge object, raising ``InputError`` that names the file and line."""

        def bad(msg: str) -> InputError:
            return InputError(path, msg, line=line)

        if not isinstance(obj, dict):
            raise bad("an edge must be a JSON object")
        required = ("edge_id", "log_path", "a", "b", "kind", "guess", "estimate")
        missing = [k for k in required if k not in obj]
        if missing:
            raise bad(f"edge lacks {', '.join(missing)}")
        if obj["kind"] not in KINDS:
            raise bad(f"unknown kind {obj['kind']!r} (expected one of {', '.join(KINDS)})")
        label = obj.get("label")
        if label is not None and label not in LABELS:
            raise bad(f"unknown label {label!r} (expected one of {', '.join(LABELS)} or null)")

        def pose(key: str, optional: bool = False) -> PoseList | None:
            value = obj.get(key)
            if value is None and optional:
                return None
            try:
                arr = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                raise bad(f"{key} must be [x, y, theta]") from None
            if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                raise bad(f"{key} must be three finite numbers [x, y, theta]")
            return [float(v) for v in arr]

        try:
            a, b = int(obj["a"]), int(obj["b"])
        except (TypeError, ValueError):
            raise bad("a and b must be scan indices") from None
        return cls(
            edge_id=str(obj["edge_id"]),
            log_path=str(obj["log_path"]),
            log_sha256=str(obj.get("log_sha256", "")),
            a=a,
            b=b,
            timestamp_a=_float_or_nan(obj.get("timestamp_a")),
            timestamp_b=_float_or_nan(obj.get("timestamp_b")),
            kind=obj["kind"],
            guess=pose("guess") or [],
            estimate=pose("estimate") or [],
            match=dict(obj.get("match") or {}),
            reference=pose("reference", optional=True),
            label=label,
            params=dict(obj.get("params") or {}),
        )


def _float_or_nan(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _finite_or_none(value: float) -> float | None:
    # JSON has no NaN; logs without a clock give scans no timestamp.
    return value if math.isfinite(value) else None


def write_edges(path: str | Path, edges: Iterable[Edge]) -> int:
    """Writes edges as JSONL atomically (a crash never leaves half a file). Returns the count."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    count = 0
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            for edge in edges:
                f.write(json.dumps(edge.to_json(), separators=(",", ":")) + "\n")
                count += 1
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return count


def read_edges(path: str | Path) -> list[Edge]:
    """Reads a JSONL edge file; a malformed line raises ``InputError`` with its line number."""
    path = Path(path)
    if path.is_dir():
        raise InputError(path, "is a folder, not an edges file")
    if not path.is_file():
        raise InputError(path, "no such file")
    edges = []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise InputError(
            path, f"not a text edges file ({exc.reason} at byte {exc.start})"
        ) from None
    for lineno, text in enumerate(lines, start=1):
        if not text.strip():
            continue
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(
                path, f"not JSON ({exc.msg} at column {exc.colno})", line=lineno
            ) from None
        edges.append(Edge.from_json(obj, path, lineno))
    if not edges:
        raise InputError(path, "holds no edges")
    return edges
