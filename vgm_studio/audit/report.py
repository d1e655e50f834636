"""What an audit tells its user: a line, the ``--json`` document and a ``--markdown`` page."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vgm_studio.audit.run import AuditResult, Verdict
from vgm_studio.graph.metrics import RelationErrors
from vgm_studio.slam.report import finite_json

# Flagged edges listed on the markdown page; the JSON lists every edge.
_LISTED = 60


def counts(result: AuditResult) -> dict[str, Any]:
    """The totals of the ``--json`` document."""
    v = result.verdicts
    loops = [x for x in v if x.edge.kind == "loop"]
    injected = [x for x in loops if x.edge.injected]
    flagged_loops = [x for x in loops if x.decision == "flagged"]
    caught = sum(x.decision == "flagged" for x in injected)
    out: dict[str, Any] = {
        "vertices": len(result.input.graph),
        "edges_total": len(v),
        "sequential_total": len(v) - len(loops),
        "loops_total": len(loops),
        "flagged_total": sum(x.decision == "flagged" for x in v),
        "flagged_sequential": sum(x.decision == "flagged" and x.edge.kind != "loop" for x in v),
        "flagged_loops": len(flagged_loops),
        "injected_false_loops": len(injected),
        "injected_flagged": caught,
    }
    if injected:
        out["injected_recall"] = caught / len(injected)
        out["flag_precision"] = caught / len(flagged_loops) if flagged_loops else None
    return out


def edge_json(v: Verdict, ids: Sequence[int]) -> dict[str, Any]:
    """One edge of the ``--json`` document: the graph's ids, what was decided and why."""
    e = v.edge
    doc: dict[str, Any] = {
        "from": int(ids[e.a]),
        "to": int(ids[e.b]),
        "kind": e.kind,
        "decision": v.decision,
        "reason": v.reason,
        "p_success": e.p_success,
        "injected": e.injected,
        "line": v.line or None,
        "validator": "kept" if e.validated else "flagged",
        "consistency": e.consistency,
        "measurement": [float(x) for x in e.guess],
    }
    if v.rematch is not None:
        doc["rematch"] = v.rematch.to_json()
    return doc


def audit_summary(
    result: AuditResult,
    errors: dict[str, RelationErrors] | None,
    settings: dict[str, Any],
    seconds: float,
) -> dict[str, Any]:
    """The ``--json`` document: errors under ``input``/``before``/``after`` (the keys of
    ``slam``'s), the totals, the timing and every edge."""
    graph = result.input.graph
    doc: dict[str, Any] = {"graph": str(graph.path), "format": graph.format}
    if errors is not None:
        doc.update({name: err.to_json() for name, err in errors.items()})
    doc.update(counts(result))
    doc.update(
        {
            "threshold": result.run.threshold,
            "seconds": seconds,
            "stage_seconds": result.seconds,
            "judged_per_second": result.judged_per_second,
            "settings": settings,
            "edges": [edge_json(v, graph.ids.tolist()) for v in result.verdicts],
        }
    )
    out: dict[str, Any] = finite_json(doc)
    return out


def audit_line(result: AuditResult) -> str:
    """One line for the terminal."""
    c = counts(result)
    text = (
        f"edges: {c['edges_total']:,} judged ({c['sequential_total']:,} sequential, "
        f"{c['loops_total']:,} loops); flagged: {c['flagged_sequential']} sequential, "
        f"{c['flagged_loops']} loops"
    )
    if c["injected_false_loops"]:
        text += f"; injected false loops flagged: {c['injected_flagged']} of "
        text += f"{c['injected_false_loops']}"
    return text


def audit_markdown(doc: dict[str, Any], pictures: Sequence[Path] = ()) -> str:
    """The ``--json`` document as a page a person reads (a CI summary takes it as it is)."""
    lines = [f"# Audit of `{doc['graph']}`", ""]
    rows = [
        ("vertices", doc["vertices"]),
        ("edges judged", doc["edges_total"]),
        ("sequential flagged", f"{doc['flagged_sequential']} of {doc['sequential_total']}"),
        ("loops flagged", f"{doc['flagged_loops']} of {doc['loops_total']}"),
    ]
    if doc["injected_false_loops"]:
        rows.append(
            (
                "injected false loops flagged",
                f"{doc['injected_flagged']} of {doc['injected_false_loops']}",
            )
        )
    rows.append(("time", f"{doc['seconds']:.1f} s"))
    lines += ["| | |", "|---|---|", *(f"| {k} | {v} |" for k, v in rows), ""]
    errors = [k for k in ("input", "before", "after") if isinstance(doc.get(k), dict)]
    if errors:
        lines += [
            "## Relation error",
            "",
            "| graph | trans mean m | rot mean ° | relations |",
            "|---|---|---|---|",
        ]
        for k in errors:
            e = doc[k]
            lines.append(
                f"| {k} | {_num(e['trans_mean'], 4)} | {_num(e['rot_mean_deg'], 3)} | {e['n']} |"
            )
        lines.append("")
    # Loops first, the surest failures first: what a person debugging a map looks for.
    flagged = sorted(
        (e for e in doc["edges"] if e["decision"] == "flagged"),
        key=lambda e: (e["kind"] != "loop", e["p_success"] if e["p_success"] is not None else 1),
    )
    lines += [f"## Flagged edges ({len(flagged)})", ""]
    if flagged:
        lines += ["| from | to | kind | p(success) | reason |", "|---|---|---|---|---|"]
        for e in flagged[:_LISTED]:
            kind = e["kind"] + (" (injected)" if e["injected"] else "")
            lines.append(
                f"| {e['from']} | {e['to']} | {kind} | {_num(e['p_success'], 2)} | {e['reason']} |"
            )
        if len(flagged) > _LISTED:
            lines.append(f"\n{len(flagged) - _LISTED} more in the JSON report.")
        lines.append("")
    for path in pictures:
        lines += [f"![{path.stem}]({path.as_posix()})", ""]
    return "\n".join(lines)


def _num(value: Any, digits: int) -> str:
    if not isinstance(value, int | float) or not math.isfinite(value):
        return "n/a"
    return f"{value:.{digits}f}"
