"""The validator's word on a graph's edges, read as an audit reads it.

Under its cut the scans fail an edge, unless a loop's scans share too little of their view to
say (``judge.shared_view``); between the cut and the loop cut of validation a loop is unsure.
``Reasons`` puts each decision in a line a person reads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vgm_studio.audit.config import AuditConfig
from vgm_studio.audit.inputs import AuditInput
from vgm_studio.audit.judge import Rematch, shared_view
from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.model.context import DEFAULT_CONTEXT, Context, Placements, walk
from vgm_studio.progress import counter
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.pipeline import MIN_POINTS, dense_reference
from vgm_studio.slam.validation import EdgeValidator, LocalMaps

# Edges the validator reads at once: its batches fill, and the bar moves often enough.
_CHUNK = 512


@dataclass
class Judgement:
    """The validator's word on every edge, and what the audit read it against.

    Attributes:
        threshold: The checkpoint's threshold (NaN without a model).
        cut: Under this p a pair's scans fail (``AuditConfig.flag_below``).
        bar: The loop cut of validation: at or over it a loop is sure.
        views: Each judged loop's shared view (``judge.shared_view``), by edge index.
        min_view: Under this the scans cannot judge a loop.
    """

    threshold: float
    cut: float
    bar: float
    views: dict[int, float]
    min_view: float

    def unsure(self, k: int, edge: SlamEdge) -> bool:
        """A loop the validator passed without vouching for it."""
        if edge.kind != "loop" or math.isnan(edge.p_success):
            return False
        return not edge.p_success >= self.bar or self.views.get(k, 1.0) < self.min_view


def judge_edges(
    validator: EdgeValidator,
    config: AuditConfig,
    scans: Sequence[Scan],
    edges: Sequence[SlamEdge],
    progress: bool,
) -> Judgement:
    """Runs the validator over the edges it can judge and reads its p as an audit does: a
    failure below the cut, where a loop's scans share enough view; else kept, for now."""
    judged = [k for k, e in enumerate(edges) if judgeable(e, scans)]
    bar = counter(len(judged), "judging edges", "edge", enabled=progress)
    try:
        for k in range(0, len(judged), _CHUNK):
            chunk = [edges[i] for i in judged[k : k + _CHUNK]]
            validator(chunk)
            bar.update(len(chunk))
    finally:
        bar.close()
    threshold = validator.threshold
    cut = config.flag_below if config.flag_below is not None else threshold
    loop_bar = validator.loop_bar
    views: dict[int, float] = {}
    if not math.isnan(cut):
        margin = DEFAULT_CONTEXT.view_margin
        for i in judged:
            e = edges[i]
            failed = e.p_success < cut
            if e.kind == "loop":
                views[i] = shared_view(scans[e.a], scans[e.b], e.estimate, margin)
                failed = failed and views[i] >= config.min_shared_view
            e.validated = e.kept = not failed
    return Judgement(
        threshold, cut, math.nan if loop_bar is None else loop_bar, views, config.min_shared_view
    )


def make_validator(
    inp: AuditInput, config: AuditConfig, scans: Sequence[Scan], ahead: bool
) -> EdgeValidator:
    """The validator, its local maps drawn from the log: from ``scans``, the vertices' scans
    that keep their points, where the graph's own scans are the log (a map asks for a
    vertex's points once per edge it is in: 65,000 times on Killian Court); ``ahead`` places
    the neighbours in a worker process meanwhile (``slam.placing``)."""
    reference = dense_reference(inp.log, inp.scan_poses)
    log_scans = scans if inp.inline else inp.log.scans
    local = LocalMaps(log_scans, inp.scan_poses, inp.vertex_scans, ahead)
    return EdgeValidator(
        config.validation,
        scans,
        None if reference is None else reference[inp.vertex_scans],
        local,
    )


def chain_placements(
    inp: AuditInput, edges: Sequence[SlamEdge], again: Sequence[Rematch], context: Context
) -> Placements:
    """Of a graph's own scans (the log), the neighbours each vertex's local map takes
    (``walk`` with ``context``) placed by the re-matches of the sequential edges between
    them, composed over steps that all held (as ``LocalMapper.placed`` holds a match). It
    spares a match per neighbour, four per vertex: 1 s of Killian Court's 4 s of validation
    where a fixed reach of steps missed the neighbours of a robot standing still."""
    count = len(inp.log)
    steps = [np.zeros(3)] * max(count - 1, 0)
    broken = np.ones(max(count - 1, 0), dtype=np.int64)  # steps whose re-match did not hold
    for e, r in zip(edges, again, strict=True):
        if e.kind == "sequential" and r.converged and r.inlier_ratio >= context.min_inliers:
            steps[e.a], broken[e.a] = r.match.estimate, 0
    # Vertex j in k's frame is between(along[k], along[j]); it holds where no broken step
    # lies between them.
    along = np.zeros((count, 3))
    for k in range(1, count):
        along[k] = se2.compose(along[k - 1], steps[k - 1])
    breaks = np.concatenate([[0], np.cumsum(broken)])
    placed: Placements = {}
    for k in range(count):
        for j in walk(inp.scan_poses, k, context):
            held = breaks[j] == breaks[k]
            placed[(k, j)] = se2.between(along[k], along[j]) if held else None
    return placed


def judgeable(edge: SlamEdge, scans: Sequence[Scan]) -> bool:
    return min(len(scans[edge.a].points()), len(scans[edge.b].points())) >= MIN_POINTS


class Reasons:
    """Why each edge was kept or flagged, in a line a person reads."""

    def __init__(
        self, judgement: Judgement, rescued: dict[int, int], scans: Sequence[Scan]
    ) -> None:
        self._j, self._rescued, self._scans = judgement, rescued, scans

    def __call__(self, k: int, e: SlamEdge) -> str:
        j = self._j
        if not judgeable(e, self._scans):
            fewest = min(len(self._scans[e.a].points()), len(self._scans[e.b].points()))
            return f"not judged: a scan with {fewest} points"
        if math.isnan(e.p_success):
            return "kept: no validator" if e.kept else "flagged"
        p = f"p {e.p_success:.2f}"
        view = j.views.get(k)
        if k in self._rescued:
            return (
                f"kept: the scans fail ({p} < {j.cut:.2f}), but {self._rescued[k]} loops near "
                "it close consistent cycles with it"
            )
        if not e.validated:
            if e.kind == "sequential":
                return (
                    f"validator: {p} < {j.cut:.2f}; kept in the chain at an odometry step's width"
                )
            return (
                f"validator: {p} < {j.cut:.2f} with {view or 0:.0%} of the view shared, "
                "and no loop near it agrees"
            )
        if e.consistency == "rejected":
            return f"consistency: disagrees with the loops near it and the chain ({p})"
        if e.kind == "sequential":
            return f"kept: {p}"
        if view is not None and view < j.min_view and e.p_success < j.cut:
            return (
                f"kept: the scans share {view:.0%} of their view, too little to judge ({p}); "
                "consistent with the loops near it"
            )
        sure = "" if e.p_success >= j.bar else " (unsure)"
        return f"kept: {p}{sure}; consistent with the loops near it"
