"""A run's loops as an edges file: every loop the front end matched, what it decided, and,
where the log has reference poses, whether the match was right.

``vgm-studio slam --loops-out`` writes them. They are not the benchmark's loop candidates: the
window and place searches found them and the loop matcher placed them against a submap, so
they are the pairs a validator meets in a SLAM run. Open the file in the studio to look at
them one by one, or train on it.
"""

from __future__ import annotations

import math
from collections import Counter
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
    injected: bool = False,
) -> list[Edge]:
    """The run's matched loops (injected false loops left out unless ``injected``) as edges
    between log scans; ``chosen`` names other edges of the run instead (an audit's flagged
    ones).

    Each edge's ``match`` holds the loop matcher's figures and, under ``slam``, the run's own
    view of it (``decisions``): where the candidate came from, p(success) and the cut it was
    held to, the validator's and the consistency check's decisions and the check's group,
    whether it went into the graph, the after graph's residual on it, and the keyframe
    indices. With reference poses each edge is labelled as ``candidates`` labels its edges (a
    failure the scans contradict is ambiguous).

    Args:
        log: The log the run read, with its reference poses where it has them.
        result: The run.
        params: How the log was read (``LogSource.params``), kept with every edge so the
            studio reopens the log the same way.
        thresholds: Label thresholds.
        chosen: The run's edges to write, instead of its matched loops.
        injected: Write the injected false loops too (``--inject-false-loops``): in the
            studio they show what the run made of a loop known to be wrong.
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
            if e.kind == "loop" and (injected or not e.injected) and e.match.covariance is not None
        ]
    groups = Counter(e.group for e in result.edges if e.group is not None)
    kept_in = Counter(e.group for e in result.edges if e.group is not None and e.kept)
    for e in chosen:
        a, b = int(result.keyframes[e.a]), int(result.keyframes[e.b])
        estimate = [float(v) for v in e.estimate]
        group = None
        if e.group is not None:
            group = {"id": e.group, "checked": groups[e.group], "kept": kept_in[e.group]}
        figures = {**e.match.figures(), "slam": decisions(e, result, group)}
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


def decisions(e: SlamEdge, result: SlamResult, group: dict[str, int] | None) -> dict[str, Any]:
    """What the run decided about ``e``, as ``match["slam"]`` holds it.

    ``cut`` is the p(success) a loop needed (the run's loop bar, else the model's threshold;
    None without a model). ``residual`` is how far the after graph's relative pose of the two
    keyframes lies from the edge's measurement (metres, degrees): small where the graph took
    the edge in, large where the edge fought the rest of the graph or was left out and the
    graph went elsewhere. ``group`` is the consistency check the loop was judged in: its
    number in the run, how many loops it checked and how many it kept.
    """
    bar = result.loop_bar if result.loop_bar is not None else result.threshold
    after = result.after.poses
    residual = None
    if max(e.a, e.b) < len(after):
        xy, theta = se2.pose_error(se2.between(after[e.a], after[e.b]), e.estimate)
        residual = {"metres": float(xy), "degrees": math.degrees(float(theta))}
    return {
        "source": e.source,
        "p_success": None if math.isnan(e.p_success) else e.p_success,
        "cut": None if bar is None or math.isnan(bar) else float(bar),
        "validated": e.validated,
        "kept": e.kept,
        "consistency": e.consistency,
        "group": group,
        "injected": e.injected,
        "residual": residual,
        "keyframes": [e.a, e.b],
    }
