"""A run's loops as an edges file: every loop the front end matched, what it decided, and,
where the log has reference poses, whether the match was right.

``vgm-studio slam --loops-out`` writes them. They are not the benchmark's loop candidates: the
window and place searches found them and the loop matcher placed them against a submap, so
they are the pairs a validator meets in a SLAM run. Open the file in the studio to look at
them one by one, or train on it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vgm_studio.core import se2
from vgm_studio.datasets.scans import ScanLog
from vgm_studio.matching.candidates import checked_label
from vgm_studio.matching.edges import Edge, Label, edge_id
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.matching.reference_labels import LabelThresholds
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.pipeline import SlamResult, dense_reference


def loop_edges(
    log: ScanLog,
    result: SlamResult,
    params: dict[str, Any],
    thresholds: LabelThresholds | None = None,
    chosen: Sequence[SlamEdge] | None = None,
) -> list[Edge]:
    """The run's matched loops (injected false loops left out) as edges between log scans;
    ``chosen`` names other edges of the run instead (an audit's flagged ones).

    Each edge's ``match`` holds the loop matcher's figures and, under ``slam``, the run's own
    view of it: where the candidate came from, p(success), the validator's and the consistency
    check's decisions, and the keyframe indices. With reference poses each edge is labelled
    as ``candidates`` labels its edges (a failure the scans contradict is ambiguous).

    Args:
        log: The log the run read, with its reference poses where it has them.
        result: The run.
        params: How the log was read (``LogSource.params``), kept with every edge so the
            studio reopens the log the same way.
        thresholds: Label thresholds.
    """
    thresholds = thresholds or LabelThresholds()
    reference = dense_reference(log, result.odometry)
    matcher = ScanMatcher()
    mount = "" if log.mount is None else log.mount.id_text()
    log_path = str(Path(log.path).resolve())
    out = []
    if chosen is None:
        chosen = [
            e
            for e in result.edges
            if e.kind == "loop" and not e.injected and e.match.covariance is not None
        ]
    for e in chosen:
        a, b = int(result.keyframes[e.a]), int(result.keyframes[e.b])
        estimate = [float(v) for v in e.estimate]
        figures = {**e.match.figures(), "slam": _decisions(e)}
        label: Label | None = None
        relative = None
        if reference is not None:
            relative = se2.between(reference[a], reference[b])
            sa, sb = log.scans[a], log.scans[b]
            label, check = checked_label(sa, sb, relative, e.estimate, matcher, thresholds)
            if check is not None:
                figures["reference_check"] = check
        out.append(
            Edge(
                edge_id=edge_id(log.content_hash, a, b, estimate, mount),
                log_path=log_path,
                log_sha256=log.content_hash,
                a=a,
                b=b,
                timestamp_a=log.scans[a].timestamp,
                timestamp_b=log.scans[b].timestamp,
                kind=e.kind,
                guess=[float(v) for v in e.guess],
                estimate=estimate,
                match=figures,
                reference=None if relative is None else [float(v) for v in relative],
                label=label,
                params=params,
            )
        )
    return out


def _decisions(e: SlamEdge) -> dict[str, Any]:
    return {
        "source": e.source,
        "p_success": None if math.isnan(e.p_success) else e.p_success,
        "validated": e.validated,
        "kept": e.kept,
        "consistency": e.consistency,
        "keyframes": [e.a, e.b],
    }
