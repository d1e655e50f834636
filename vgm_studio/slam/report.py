"""What a run tells its user: relation errors, edge counts, maps, the JSON summary."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.datasets.relations import MatchedRelation
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.graph.metrics import RelationErrors, relation_errors
from vgm_studio.maps.config import MapConfig
from vgm_studio.maps.occupancy import OccupancyGrid, build_map
from vgm_studio.matching.edges import edge_id
from vgm_studio.matching.reference_labels import LabelThresholds, reference_label
from vgm_studio.slam.edges import LOOP_SOURCES, SlamEdge
from vgm_studio.slam.pipeline import SlamResult, dense_reference

TRAJECTORIES = ("odometry", "before", "after")
_SOURCES = (*LOOP_SOURCES, "injected")


def keyframe_trajectories(result: SlamResult) -> dict[str, NDArray[np.float64]]:
    """The three keyframe trajectories by name: odometry (``input`` for an audited graph),
    before, after."""
    start = (
        {"odometry": result.odometry_keyframes} if result.given is None else {"input": result.given}
    )
    return {**start, "before": result.before.poses, "after": result.after.poses}


def run_maps(log: ScanLog, result: SlamResult, config: MapConfig) -> dict[str, OccupancyGrid]:
    """Occupancy maps of the keyframe scans placed by each trajectory."""
    points = [log.scans[i].points() for i in result.keyframes]
    return {
        name: build_map(poses, points, config)
        for name, poses in keyframe_trajectories(result).items()
    }


# The loops on the edges map, in drawing order (rejected under kept), as RGB.
LOOP_COLOURS: dict[str, tuple[int, int, int]] = {
    "rejected by validator": (230, 40, 40),
    "rejected by consistency": (255, 150, 0),
    "injected, kept": (220, 40, 220),
    "kept (window)": (40, 120, 255),
    "kept (place)": (20, 170, 60),
    "kept (sweep)": (150, 90, 255),
    "kept (graph)": (70, 70, 230),
}


def loop_segments(
    result: SlamResult,
) -> list[tuple[NDArray[np.float64], NDArray[np.float64], str]]:
    """Each loop edge as a segment of the ``after`` map, named by its decisions."""
    poses = result.after.poses
    out = []
    for e in result.edges:
        if e.kind != "loop":
            continue
        if not e.validated:
            kind = "rejected by validator"
        elif e.consistency == "rejected":
            kind = "rejected by consistency"
        elif e.injected:
            kind = "injected, kept"
        else:
            kind = f"kept ({e.source})"
        out.append((poses[e.a, :2], poses[e.b, :2], kind))
    return out


@dataclass
class EdgeCounts:
    """How many edges of each kind validation kept and rejected."""

    total: int
    kept: int
    rejected: int
    loops: int
    loops_kept: int
    injected: int
    injected_kept: int
    by_source: dict[str, int] = field(default_factory=dict)
    validated: int = 0
    consistency_rejected: int = 0
    at_match: int = 0

    @classmethod
    def of(cls, result: SlamResult) -> EdgeCounts:
        loops = [e for e in result.edges if e.kind == "loop"]
        injected = [e for e in loops if e.injected]
        return cls(
            total=len(result.edges),
            kept=result.edges_kept,
            rejected=len(result.edges) - result.edges_kept,
            loops=len(loops),
            loops_kept=sum(e.kept for e in loops),
            injected=len(injected),
            injected_kept=sum(e.kept for e in injected),
            by_source={s: sum(e.source == s for e in loops) for s in _SOURCES},
            validated=sum(e.validated for e in loops),
            consistency_rejected=sum(e.consistency == "rejected" for e in loops),
            at_match=sum(e.at_match for e in result.edges),
        )


def errors_of(
    result: SlamResult, relations: Sequence[MatchedRelation] | None
) -> dict[str, RelationErrors] | None:
    """Relation errors of each trajectory, every scan placed by its keyframes: the graphs'
    with the scans between keyframes refined onto them, the odometry's (or an audited
    graph's input) by the odometry alone. None without relations."""
    if relations is None:
        return None
    return {
        name: relation_errors(result.scan_poses(poses, name in ("before", "after")), relations)
        for name, poses in keyframe_trajectories(result).items()
    }


def summary(
    result: SlamResult,
    errors: dict[str, RelationErrors] | None,
    settings: dict[str, Any],
    seconds: float,
    log: ScanLog | None = None,
    read: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``--json`` document.

    With ``log`` it also says which log the run read and where its keyframes lie
    (``run_identity``), and each edge its scans (``scan_edges``): ``vgm-studio compare``
    matches two runs' loops by those scans, since two runs of one log may pick other
    keyframes.
    """
    counts = EdgeCounts.of(result)
    out: dict[str, Any] = {}
    if errors is not None:
        out.update({name: err.to_json() for name, err in errors.items()})
    out.update(
        {
            "edges_total": counts.total,
            "edges_kept": counts.kept,
            "edges_rejected": counts.rejected,
            "loops_total": counts.loops,
            "loops_kept": counts.loops_kept,
            "injected_false_loops": counts.injected,
            "injected_false_loops_kept": counts.injected_kept,
            "loops_by_source": counts.by_source,
            "loops_validator_kept": counts.validated,
            "loops_consistency_rejected": counts.consistency_rejected,
            "sequential_at_match": counts.at_match,
            "gnc_rejected": {
                "before": int(np.sum(result.before.weights < 0.5)),
                "after": int(np.sum(result.after.weights < 0.5)),
            },
            "isam2_restarts": result.isam2_restarts,
            "keyframes": len(result.keyframes),
            "scans": len(result.odometry),
            "seconds": seconds,
            "stage_seconds": result.seconds,
            "settings": settings,
            "edges": [edge_json(e) for e in result.edges],
        }
    )
    if log is not None:
        out.update(run_identity(log, result, read))
        scan_edges(out["edges"], log, result)
    finite: dict[str, Any] = finite_json(out)
    return finite


def edge_json(edge: SlamEdge) -> dict[str, Any]:
    """One edge's provenance and both decisions, for the ``--json`` document."""
    return {
        "kind": edge.kind,
        "a": edge.a,
        "b": edge.b,
        "source": edge.source,
        "validator": "kept" if edge.validated else "rejected",
        "p_success": edge.p_success,
        "consistency": edge.consistency,
        "overlap": edge.overlap,
        "kept": edge.kept,
        "at_match": edge.at_match,
        "estimate": [float(v) for v in edge.estimate],
    }


def run_identity(log: ScanLog, result: SlamResult, read: dict[str, Any] | None) -> dict[str, Any]:
    """Which log a run read (its content hash: the same bytes under any path) and how, the
    keyframes' scan indices and timestamps, and the after poses of the keyframes.

    ``compare`` refuses two runs of different logs by the hash, matches keyframes across
    runs by scan, and draws the after maps from these poses and the log's scans.
    """
    return {
        "log": {
            "path": str(Path(log.path).resolve()),
            "sha256": log.content_hash,
            "mount": "" if log.mount is None else log.mount.id_text(),
            "read": read or {},
        },
        "keyframe_scans": [int(k) for k in result.keyframes],
        "keyframe_times": [float(log.scans[int(k)].timestamp) for k in result.keyframes],
        "after_poses": [[float(v) for v in pose] for pose in result.after.poses],
    }


def scan_edges(edges: list[dict[str, Any]], log: ScanLog, result: SlamResult) -> None:
    """Adds each edge's log scans (``scan_a``, ``scan_b``) to its JSON entry, and to each
    loop the id ``--loops-out`` and the studio give it (``matching.edges.edge_id``).

    Where the log has reference poses, each loop also gets ``reference_error`` (metres,
    degrees) and ``reference_label``: success, failure or ambiguous by those distances alone
    (``--loops-out`` also checks a failure against the scans, which costs a match each).
    """
    mount = "" if log.mount is None else log.mount.id_text()
    reference = dense_reference(log, result.odometry)
    thresholds = LabelThresholds()
    for doc, e in zip(edges, result.edges, strict=True):
        a, b = int(result.keyframes[e.a]), int(result.keyframes[e.b])
        doc["scan_a"], doc["scan_b"] = a, b
        if e.kind != "loop":
            continue
        doc["edge_id"] = edge_id(log.content_hash, a, b, [float(v) for v in e.estimate], mount)
        if reference is None:
            continue
        relative = se2.between(reference[a], reference[b])
        exy, eth = se2.pose_error(relative, e.estimate)
        doc["reference_error"] = [float(exy), math.degrees(eth)]
        doc["reference_label"] = reference_label(relative, e.estimate, thresholds)


def finite_json(value: Any) -> Any:
    """``value`` with every float that is not finite made None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [finite_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def table(errors: dict[str, RelationErrors]) -> str:
    """The relation errors as a plain text table."""
    lines = [
        f"{'trajectory':<10} {'trans mean m':>12} {'trans std m':>12} "
        f"{'rot mean °':>11} {'rot std °':>10} {'n':>6}"
    ]
    for name, e in errors.items():
        lines.append(
            f"{name:<10} {e.trans_mean:>12.4f} {e.trans_std:>12.4f} "
            f"{e.rot_mean_deg:>11.3f} {e.rot_std_deg:>10.3f} {e.n:>6}"
        )
    return "\n".join(lines)


def edge_line(result: SlamResult) -> str:
    c = EdgeCounts.of(result)
    text = (
        f"edges: {c.total} matched, {c.kept} kept, {c.rejected} rejected; "
        f"loops: {c.loops} proposed ({c.by_source['window']} by window, "
        f"{c.by_source['place']} by place, {c.by_source['sweep']} by the final sweep), "
        f"{c.validated} passed the validator, "
        f"{c.loops_kept} kept after the consistency check"
    )
    if c.injected:
        text += f"; injected false loops: {c.injected_kept} of {c.injected} kept"
    if result.isam2_restarts:
        text += "; iSAM2 rebuilt with QR once (gtsam called the long chain indeterminate)"
    return text
