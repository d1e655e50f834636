"""A SLAM run's decisions about its edges, as the panel shows them and the queues sort by them.

``vgm-studio slam --loops-out`` and ``audit --edges-out`` write, under each edge's
``match["slam"]``, what the run made of it (``slam.loop_edges.decisions``): where the candidate
came from, the validator's p(success) and the cut it was held to, the consistency check's word
and group, whether the edge went into the graph, and the after graph's residual on it. The
file is input from outside: every value is checked for its type here and shown through
``plain``, never trusted as markup.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from vgm_studio.core import se2
from vgm_studio.matching.edges import Edge
from vgm_studio.studio.panel import plain
from vgm_studio.studio.queues import RUN_QUEUES, RunDecisions, Snapshot, run_order

SOURCES = {
    "window": "window search around the estimate",
    "place": "place recognition",
    "sweep": "final sweep",
    "injected": "injected (a false loop put in on purpose)",
    "graph": "the audited graph's own edge",
    "odometry": "odometry",
}
# How the header names each of a run's queues, short enough for one line.
_COUNTED = ("kept", "rejected", "kept, labelled failure", "rejected, labelled success")


def _number(value: Any) -> float | None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    return float(value) if ok and math.isfinite(value) else None


def _count(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


@dataclass(frozen=True)
class Decisions:
    """One edge's ``match["slam"]``, read defensively (a missing or odd value is None).

    Attributes:
        kept: The edge went into the run's graph.
        source: Where the candidate came from (``slam.edges.EdgeSource``).
        p_success: The validator's p(success); None without a model.
        cut: The p(success) a loop needed; None without a model.
        validated: The validator's own decision.
        consistency: ``kept``, ``rejected`` or ``not-checked``.
        group: (number, loops checked, loops kept) of the consistency check it was in.
        injected: A false loop put in on purpose.
        residual: (metres, degrees) between the edge and the after graph's relative pose.
    """

    kept: bool
    source: str | None = None
    p_success: float | None = None
    cut: float | None = None
    validated: bool | None = None
    consistency: str | None = None
    group: tuple[int, int | None, int | None] | None = None
    injected: bool = False
    residual: tuple[float, float] | None = None

    @classmethod
    def of(cls, edge: Edge) -> Decisions | None:
        """The run's decisions on ``edge``; None where it carries none."""
        slam = edge.match.get("slam")
        if not isinstance(slam, dict) or not isinstance(slam.get("kept"), bool):
            return None
        group = slam.get("group")
        gid = _count(group.get("id")) if isinstance(group, dict) else None
        residual = slam.get("residual")
        metres = _number(residual.get("metres")) if isinstance(residual, dict) else None
        degrees = _number(residual.get("degrees")) if isinstance(residual, dict) else None
        validated = slam.get("validated")
        return cls(
            kept=slam["kept"],
            source=slam["source"] if isinstance(slam.get("source"), str) else None,
            p_success=_number(slam.get("p_success")),
            cut=_number(slam.get("cut")),
            validated=validated if isinstance(validated, bool) else None,
            consistency=slam["consistency"] if isinstance(slam.get("consistency"), str) else None,
            group=None
            if gid is None or not isinstance(group, dict)
            else (gid, _count(group.get("checked")), _count(group.get("kept"))),
            injected=slam.get("injected") is True,
            residual=None if metres is None or degrees is None else (metres, degrees),
        )


def run_of(edges: Iterable[Edge]) -> RunDecisions:
    """A run's decisions over a workspace's edges, with their reference labels and errors."""
    run = RunDecisions()
    for edge in edges:
        decided = Decisions.of(edge)
        if decided is not None:
            run.kept[edge.edge_id] = decided.kept
        if edge.label is not None:
            run.reference[edge.edge_id] = edge.label
        if edge.reference is not None:
            run.off[edge.edge_id] = se2.pose_error(edge.reference, edge.estimate)[0]
    return run


def decision_rows(edge: Edge) -> list[tuple[str, str]]:
    """The run's decisions on ``edge`` as rows of the panel's facts table (none without)."""
    d = Decisions.of(edge)
    if d is None:
        return []
    source = SOURCES.get(d.source or "", plain(d.source or "unknown"))
    rows = [("run: source", source)]
    rows.append(("run: validator", _validator(d)))
    rows.append(("run: consistency", _consistency(d)))
    went = "**kept** in the graph" if d.kept else "**rejected**, not in the graph"
    rows.append(("run: decision", went))
    if d.residual is not None:
        metres, degrees = d.residual
        rows.append(
            ("run: residual", f"{100 * metres:.1f} cm, {degrees:.1f}° (after graph vs this edge)")
        )
    audit = edge.match.get("audit")
    if isinstance(audit, dict) and audit.get("reason"):
        rows.append(("audit", f"flagged: {plain(audit['reason'], 160)}"))
    return rows


def _validator(d: Decisions) -> str:
    passed = {True: "passed", False: "rejected", None: "?"}[d.validated]
    cut = "–" if d.cut is None else f"{d.cut:.2f}"
    if d.p_success is None:
        return f"p –, cut {cut}: {passed}"
    side = "≥" if d.cut is not None and d.p_success >= d.cut else "<"
    if d.cut is None:
        side = "·"
    return f"p {d.p_success:.2f} {side} cut {cut}: {passed}"


def _consistency(d: Decisions) -> str:
    word = plain(d.consistency or "not-checked")
    if d.group is None:
        return word
    number, checked, kept = d.group
    of = f"{checked} loops checked" if checked is not None else "loops checked"
    if kept is not None:
        of += f", {kept} kept"
    return f"{word} in group {number} ({of})"


def run_header(snap: Snapshot) -> str:
    """The counts of a run's queues as a line of the panel's header, starting with a line
    break ("" where no edge carries a run's decisions)."""
    if not snap.run.kept:
        return ""
    counts = [len(run_order(q, snap)) for q in RUN_QUEUES]
    pairs = zip(counts, _COUNTED, strict=True)
    return "  \n**run:** " + " · ".join(f"{n} {name}" for n, name in pairs)
