"""An audit: every edge of a graph judged from its scans, the loops checked as a group, and
the graph optimised again without the edges flagged.

The result is a ``SlamResult`` too (``AuditResult.run``): the vertices are its keyframes and
the graph's edges its edges, so the maps, the recording, the relation errors and the edges
file of ``slam`` serve the audit unchanged.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vgm_studio.audit.config import AuditConfig
from vgm_studio.audit.group import check_loops, widened, with_ties
from vgm_studio.audit.inject import false_loops
from vgm_studio.audit.inputs import AuditInput
from vgm_studio.audit.judge import Rematch, judge_pairs
from vgm_studio.audit.verdicts import (
    Reasons,
    chain_placements,
    judge_edges,
    make_validator,
)
from vgm_studio.core import se2
from vgm_studio.core.cpus import usable_threads
from vgm_studio.datasets.g2o import G2oEdge
from vgm_studio.graph.pose_graph import GraphEdge, optimize
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.pipeline import SlamResult


@dataclass
class Verdict:
    """What the audit made of one edge.

    Attributes:
        edge: The edge with the validator's and the group check's decisions.
        line: The line of the graph file it came from (0: injected).
        reason: Why it was kept or flagged, for a person.
        rematch: The matcher's answer from the measurement, where it was asked for.
    """

    edge: SlamEdge
    line: int
    reason: str
    rematch: Rematch | None = None

    @property
    def decision(self) -> str:
        return "kept" if self.edge.kept else "flagged"


@dataclass
class AuditResult:
    """An audit's decisions and graphs.

    Attributes:
        input: What was audited.
        run: The graph as a SLAM run: ``before`` every edge, ``after`` the cleaned graph.
        verdicts: One per edge, the graph's in file order, then the injected ones.
        seconds: Wall time per stage.
    """

    input: AuditInput
    run: SlamResult
    verdicts: list[Verdict]
    seconds: dict[str, float]

    @property
    def judged_per_second(self) -> float:
        """Edges judged (validator and group check) per second."""
        spent = self.seconds.get("validator", 0.0) + self.seconds.get("consistency", 0.0)
        return len(self.verdicts) / spent if spent > 0 else math.inf


def forward(edge: G2oEdge) -> tuple[int, int, NDArray[np.float64], NDArray[np.float64]]:
    """(a, b, z, Σ) with a < b: an edge written from the later vertex is turned round (its
    covariance carried by the measurement's adjoint, in gtsam's convention)."""
    cov = edge.covariance
    if edge.a < edge.b:
        return edge.a, edge.b, edge.measurement, cov
    z = se2.inverse(edge.measurement)
    c, s = math.cos(edge.measurement[2]), math.sin(edge.measurement[2])
    adjoint = np.array(
        [[c, -s, edge.measurement[1]], [s, c, -edge.measurement[0]], [0.0, 0.0, 1.0]]
    )
    return edge.b, edge.a, z, adjoint @ cov @ adjoint.T


def run_audit(inp: AuditInput, config: AuditConfig, progress: bool = True) -> AuditResult:
    """Judges every edge of ``inp``'s graph and optimises it again without the flagged ones.

    Raises:
        InputError: The validator cannot be set up (a missing or foreign checkpoint).
    """
    seconds: dict[str, float] = {}
    graph = inp.graph
    anchor = graph.fixed or 0
    t = time.perf_counter()
    own = [forward(e) for e in graph.edges]
    lines = [e.line for e in graph.edges]
    scans = [dataclasses.replace(inp.log.scans[i], keep_points=True) for i in inp.vertex_scans]
    matcher = ScanMatcher()
    if config.inject.count:
        estimate = optimize(graph.poses, _factors(own, graph.poses), config.graph, anchor=anchor)
        for e in false_loops(estimate.poses, graph.edges, scans, config.inject, matcher):
            own.append((e.a, e.b, e.measurement, e.covariance))
            lines.append(0)
    seconds["injecting"] = time.perf_counter() - t
    # The model loads before the pairs are matched; where the graph is tied to a log's scans,
    # its worker process places the vertices' neighbours in the log meanwhile (the matches of
    # a graph's own scans place them: ``chain_placements``).
    t = time.perf_counter()
    validator = make_validator(inp, config, scans, not inp.inline and usable_threads() > 1)
    seconds["loading"] = time.perf_counter() - t
    try:
        t = time.perf_counter()
        pairs = [(a, b, z) for a, b, z, _ in own]
        matches, again = judge_pairs(matcher, scans, pairs, config.validation.thresholds, progress)
        seconds["matching"] = time.perf_counter() - t
        edges = [
            SlamEdge(
                "sequential" if b == a + 1 else "loop",
                a,
                b,
                z,
                m,
                injected=line == 0,
                source="injected" if line == 0 else "graph",
            )
            for (a, b, z, _), m, line in zip(own, matches, lines, strict=True)
        ]
        t = time.perf_counter()
        if inp.inline:
            validator.adopt(chain_placements(inp, edges, again, validator.context))
        judgement = judge_edges(validator, config, scans, edges, progress)
    finally:
        validator.close()
    seconds["validator"] = time.perf_counter() - t
    t = time.perf_counter()
    covariances = [cov for _, _, _, cov in own]
    rescued = check_loops(
        edges,
        covariances,
        graph.poses,
        config.graph,
        config.consistency,
        config.block,
        (config.support, config.support_span),
        [judgement.unsure(k, e) for k, e in enumerate(edges)],
    )
    seconds["consistency"] = time.perf_counter() - t
    t = time.perf_counter()
    before = optimize(graph.poses, _factors(own, graph.poses), config.graph, anchor=anchor)
    kept = [_kept_factor(e, cov, config) for e, cov in zip(edges, covariances, strict=True)]
    cleaned = with_ties([f for f in kept if f is not None], graph.poses)
    after = optimize(graph.poses, cleaned, config.graph, anchor=anchor)
    seconds["back_end"] = time.perf_counter() - t
    reasons = Reasons(judgement, rescued, scans)
    verdicts = [
        Verdict(e, line, reasons(k, e), r)
        for k, (e, line, r) in enumerate(zip(edges, lines, again, strict=True))
    ]
    run = SlamResult(
        keyframes=inp.vertex_scans,
        odometry=inp.scan_poses,
        edges=edges,
        running=graph.poses,
        before=before,
        after=after,
        threshold=judgement.threshold,
        seconds=seconds,
        after_edges=cleaned,
        given=graph.poses,
    )
    return AuditResult(inp, run, verdicts, seconds)


def _factors(
    own: list[tuple[int, int, NDArray[np.float64], NDArray[np.float64]]],
    poses: NDArray[np.float64],
) -> list[GraphEdge]:
    factors = [GraphEdge(a, b, z, cov, known_inlier=b == a + 1) for a, b, z, cov in own]
    return with_ties(factors, poses)


def _kept_factor(
    edge: SlamEdge, covariance: NDArray[np.float64], config: AuditConfig
) -> GraphEdge | None:
    if edge.kept:
        return GraphEdge(edge.a, edge.b, edge.guess, covariance, edge.kind == "sequential")
    if edge.kind == "sequential":
        # The chain stays whole: the step goes in at an odometry step's width.
        return GraphEdge(edge.a, edge.b, edge.guess, widened(edge, config.graph), True)
    return None
