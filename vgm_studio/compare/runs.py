"""A run's ``--json`` document read back for comparison: which log it ran on, its relation
errors, its loops by scan pair and its keyframes' after poses.

``vgm-studio slam --json`` and ``vgm-studio audit --json`` write them. A slam document names
its log by content hash and each loop by the two scans it joins (``slam/report.py``
``run_identity``, ``scan_edges``); an audit's loops are named by the graph's vertex ids.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from vgm_studio.errors import InputError

RunKind = Literal["slam", "audit"]
# The trajectories whose relation errors a document may hold, in the order shown.
TRAJECTORIES = ("odometry", "input", "before", "after")


@dataclass(frozen=True)
class Errors:
    """One trajectory's relation error (Kümmerle et al. 2009), as the run wrote it."""

    trans_mean: float
    rot_mean_deg: float
    n: int


@dataclass(frozen=True)
class Loop:
    """One loop edge of a run and what the run decided about it.

    Attributes:
        a: The earlier end: a log scan index (slam) or a graph vertex id (audit).
        b: The later end, likewise.
        kept: Whether the edge went into the after graph.
        validator: ``kept``, ``rejected`` (slam) or ``flagged`` (audit).
        consistency: The group check's decision (``kept``, ``rejected``, ``not-checked``).
        source: Where the candidate came from (``window``, ``place``, ``sweep``,
            ``injected``; an audit's loops say ``graph``).
        p_success: The validator's p(success), None where it gave none.
        truth: ``false`` (injected, or failure against the log's reference poses), ``right``
            (success against them) or None (ambiguous, or nothing to judge by).
        why: What ``truth`` rests on, for the report.
        edge_id: The id the studio opens the loop by (slam loops only).
    """

    a: int
    b: int
    kept: bool
    validator: str
    consistency: str
    source: str
    p_success: float | None
    truth: str | None = None
    why: str = ""
    edge_id: str | None = None

    @property
    def decision(self) -> str:
        """Where the loop ended, in words: kept, or which check rejected it."""
        if self.kept:
            return "kept"
        if self.validator != "kept":
            return "rejected by validator" if self.validator == "rejected" else "flagged"
        return "rejected by consistency"


@dataclass
class Run:
    """A run's figures, as far as comparing two runs needs them.

    Attributes:
        path: The JSON file.
        kind: ``slam`` or ``audit``.
        identity: What two runs must share to be compared: the log's content hash (slam),
            the graph's file name and vertex count (audit).
        subject: The log or graph, in words, for messages.
        errors: Relation errors by trajectory (empty without relations or a reference).
        loops: Every loop edge.
        log_path: The log a slam run read (to draw its maps again), else None.
        read: How that log was read (``ReadOptions`` fields).
        keyframe_scans: (K,) scan index of each keyframe (slam only).
        after_poses: (K, 3) each keyframe's after pose (slam only).
    """

    path: Path
    kind: RunKind
    identity: str
    subject: str
    errors: dict[str, Errors]
    loops: list[Loop]
    log_path: str | None = None
    read: dict[str, Any] = field(default_factory=dict)
    keyframe_scans: NDArray[np.int64] | None = None
    after_poses: NDArray[np.float64] | None = None


def load_run(path: Path) -> Run:
    """Reads a ``slam --json`` or ``audit --json`` document.

    Raises:
        InputError: ``path: what is wrong`` for a missing or unreadable file, a file that is
            not JSON, a JSON document that is not a run, or a slam document written before
            runs named their log.
    """
    if not path.exists():
        raise InputError(path, "no such file")
    if not path.is_file():
        raise InputError(path, "not a file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read it ({exc.__class__.__name__})") from None
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("edges"), list):
        raise InputError(path, "not a run: expected the --json of vgm-studio slam or audit")
    try:
        return _audit(path, doc) if "graph" in doc else _slam(path, doc)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(path, f"not a run: a field is missing or malformed ({exc})") from None


def _errors(doc: dict[str, Any]) -> dict[str, Errors]:
    out = {}
    for name in TRAJECTORIES:
        e = doc.get(name)
        if isinstance(e, dict) and e.get("trans_mean") is not None:
            out[name] = Errors(float(e["trans_mean"]), float(e["rot_mean_deg"]), int(e["n"]))
    return out


def _slam(path: Path, doc: dict[str, Any]) -> Run:
    if "keyframes" not in doc or "loops_total" not in doc:
        raise InputError(path, "not a run: expected the --json of vgm-studio slam or audit")
    log = doc.get("log")
    if not isinstance(log, dict) or "keyframe_scans" not in doc:
        raise InputError(
            path,
            "this slam run does not name its log (written before compare existed); "
            "run vgm-studio slam --json again",
        )
    loops = [_slam_loop(e) for e in doc["edges"] if e["kind"] == "loop"]
    return Run(
        path=path,
        kind="slam",
        identity=str(log["sha256"]),
        subject=f"{Path(log['path']).name} (sha256 {str(log['sha256'])[:12]})",
        errors=_errors(doc),
        loops=loops,
        log_path=str(log["path"]),
        read=dict(log.get("read") or {}),
        keyframe_scans=np.asarray(doc["keyframe_scans"], dtype=np.int64),
        after_poses=np.asarray(doc["after_poses"], dtype=np.float64).reshape(-1, 3),
    )


def _slam_loop(e: dict[str, Any]) -> Loop:
    a, b = sorted((int(e["scan_a"]), int(e["scan_b"])))
    truth, why = None, ""
    if e.get("source") == "injected":
        truth, why = "false", "injected"
    elif e.get("reference_label") in ("failure", "success"):
        err = e.get("reference_error") or [float("nan"), float("nan")]
        truth = "false" if e["reference_label"] == "failure" else "right"
        why = f"reference: {err[0]:.2f} m, {err[1]:.1f}° off"
    return Loop(
        a=a,
        b=b,
        kept=bool(e["kept"]),
        validator=str(e["validator"]),
        consistency=str(e.get("consistency", "not-checked")),
        source=str(e.get("source", "")),
        p_success=None if e.get("p_success") is None else float(e["p_success"]),
        truth=truth,
        why=why,
        edge_id=e.get("edge_id"),
    )


def _audit(path: Path, doc: dict[str, Any]) -> Run:
    name = Path(str(doc["graph"])).name
    loops = []
    for e in doc["edges"]:
        if e["kind"] != "loop":
            continue
        a, b = sorted((int(e["from"]), int(e["to"])))
        injected = bool(e.get("injected"))
        loops.append(
            Loop(
                a=a,
                b=b,
                kept=e["decision"] == "kept",
                validator=str(e.get("validator", "kept")),
                consistency=str(e.get("consistency", "not-checked")),
                source="injected" if injected else "graph",
                p_success=None if e.get("p_success") is None else float(e["p_success"]),
                truth="false" if injected else None,
                why="injected" if injected else "",
            )
        )
    vertices = int(doc["vertices"])
    return Run(
        path=path,
        kind="audit",
        identity=f"{name}:{vertices}",
        subject=f"{name} ({vertices} vertices)",
        errors=_errors(doc),
        loops=loops,
    )


def same_subject(base: Run, new: Run) -> None:
    """Refuses two runs that cannot be compared: a slam run and an audit, or two logs.

    Raises:
        InputError: Naming the NEW file and what differs.
    """
    if base.kind != new.kind:
        raise InputError(new.path, f"{_a(new.kind)} run, but {base.path} is {_a(base.kind)} run")
    if base.identity != new.identity:
        raise InputError(
            new.path,
            f"a run of {new.subject}, but {base.path} is a run of {base.subject}: "
            "compare two runs of one log",
        )


def _a(kind: str) -> str:
    return f"an {kind}" if kind[0] in "aeiou" else f"a {kind}"
