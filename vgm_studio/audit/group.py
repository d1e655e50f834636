"""The loops the validator passed, checked as a group (``slam.consistency``'s PCM), the way
the front end of ``slam`` checks its own: along the graph's sequential chain, a block of
vertices at a time, each block's kept loops closed into the estimate before the next.

The chain is the graph's sequential edges, each with its own covariance plus the floors of
``GraphConfig`` (a graph that claims millimetres would make every cycle test fail on noise).
A sequential edge the validator flagged stays in the chain at the width of an odometry
step (``GraphConfig.odometry_sigma_*``); consecutive vertices no sequential edge joins are
tied by the graph's own estimate at a width that says nothing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.graph.config import GraphConfig
from vgm_studio.graph.pose_graph import GraphEdge, RunningEstimate
from vgm_studio.slam.config import ConsistencyConfig
from vgm_studio.slam.consistency import Loop, consistent, cycle_chi2s
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.uncertainty import UncertaintyGraph, chi2_gate

# A tie between consecutive vertices that no sequential edge joins: present so the chain is
# one graph, too wide to say anything of where the vertex is.
_UNTIED = np.diag([100.0**2, 100.0**2, math.pi**2])


def floored(covariance: NDArray[np.float64], config: GraphConfig) -> NDArray[np.float64]:
    """A graph file's covariance plus the floors every edge of ``slam`` carries."""
    floor = [config.min_sigma_xy**2] * 2 + [math.radians(config.min_sigma_theta_deg) ** 2]
    return np.asarray(covariance, dtype=np.float64) + np.diag(floor)


def widened(edge: SlamEdge, config: GraphConfig) -> NDArray[np.float64]:
    """The covariance of a flagged sequential edge: an odometry step's, over its length."""
    step = float(math.hypot(edge.guess[0], edge.guess[1]))
    sxy = config.min_sigma_xy + config.odometry_sigma_xy * step
    return np.diag([sxy**2, sxy**2, math.radians(config.odometry_sigma_theta_deg) ** 2])


def chain(
    edges: Sequence[SlamEdge],
    covariances: Sequence[NDArray[np.float64]],
    poses: NDArray[np.float64],
    config: GraphConfig,
) -> list[GraphEdge]:
    """The sequential chain as the group check reads it (see the module's docstring)."""
    out: list[GraphEdge] = []
    for e, cov in zip(edges, covariances, strict=True):
        if e.kind != "sequential":
            continue
        width = floored(cov, config) if e.validated else widened(e, config)
        out.append(GraphEdge(e.a, e.b, e.guess, width, known_inlier=True))
    return with_ties(out, poses)


def with_ties(factors: list[GraphEdge], poses: NDArray[np.float64]) -> list[GraphEdge]:
    """``factors`` and, between consecutive vertices that no sequential factor joins, a tie
    at the graph's own estimate, too wide to say anything of where the vertex is: the chain
    stays one graph (and one that solves where flagged loops held two parts together)."""
    joined = {f.b for f in factors if f.b == f.a + 1}
    ties = [
        GraphEdge(k - 1, k, se2.between(poses[k - 1], poses[k]), _UNTIED, known_inlier=True)
        for k in range(1, len(poses))
        if k not in joined
    ]
    return factors + ties


def check_loops(
    edges: Sequence[SlamEdge],
    covariances: Sequence[NDArray[np.float64]],
    poses: NDArray[np.float64],
    graph: GraphConfig,
    config: ConsistencyConfig,
    block: int,
    support: tuple[int, int] = (2, 10),
    unsure: Sequence[bool] | None = None,
) -> dict[int, int]:
    """Sets ``consistency`` and ``kept`` of the loops the validator passed, then keeps the
    loops it failed that enough kept loops near them agree with (``rescue``).

    Args:
        edges: Every edge, sequential and loop, with ``a < b``, its measurement as ``guess``
            and the validator's decision.
        covariances: Each edge's covariance as its graph gave it.
        poses: (V, 3) the graph's own estimate, for the vertices no sequential edge joins.
        graph: Floors and the width of flagged steps.
        config: The check's gate, vote and support.
        block: Vertices per block.
        support: (how many, within how many vertices at both ends) for ``rescue``.
        unsure: Per edge, the validator passed it without being sure (under its loop cut,
            or scans that share too little view to judge): such a loop must have loops near
            it that agree (``ConsistencyConfig.min_support``), as a place-recognition loop
            must in ``slam``. Where the chain is long and uncertain, a lone loop fits any
            estimate: one unverifiable false loop kept so on the Killian Court graph bent
            the map under a revisit of 20 right loops, which the check then rejected.

    Returns:
        For each loop kept by ``rescue``, by index in ``edges``, the loops that agree with it.
    """
    if not config.enabled:
        return {}
    links = chain(edges, covariances, poses, graph)
    grow = _Growth(links, len(poses), graph)
    estimate, uncertainty = grow.estimate, grow.uncertainty
    loops = sorted(
        (i for i, e in enumerate(edges) if e.kind == "loop" and e.validated),
        key=lambda i: edges[i].b,
    )
    for first in range(0, len(poses), block):
        chosen = [i for i in loops if first <= edges[i].b < first + block]
        if not chosen:
            continue
        # The chain grows to the block's end only: the searches and iSAM2 work on the part
        # that exists, as in ``slam``. The vertices after it hang off the chain's end, so
        # they change no loop's test.
        grow.to(first + block)
        checked = [
            Loop(
                edges[i].a,
                edges[i].b,
                edges[i].guess,
                floored(covariances[i], graph),
                surprise=unsure is not None and unsure[i],
            )
            for i in chosen
        ]
        flags = consistent(checked, estimate.poses, uncertainty, config, drift=uncertainty)
        closed = False
        for i, loop, ok in zip(chosen, checked, flags, strict=True):
            edges[i].consistency = "kept" if ok else "rejected"
            edges[i].kept = bool(ok)
            if ok:
                factor = GraphEdge(loop.a, loop.b, loop.measurement, loop.covariance)
                estimate.add_edge(factor)
                uncertainty.add(factor)
                closed = True
        if closed:
            estimate.update(extra_iterations=2)
    grow.to(len(poses))
    gate = chi2_gate(config.probability, 3)
    failed = [i for i, e in enumerate(edges) if e.kind == "loop" and not e.validated]
    # Support comes from the loops the group check kept and from the other failed loops: a
    # revisit the validator is unsure of throughout still agrees with itself.
    held = [i for i in loops if edges[i].kept] + failed

    def loop_of(i: int) -> Loop:
        e = edges[i]
        return Loop(e.a, e.b, e.guess, floored(covariances[i], graph))

    found = rescue(loop_of, failed, held, estimate.poses, uncertainty, gate, support)
    for i in found:
        edges[i].kept = True
        edges[i].consistency = "kept"
    return found


class _Growth:
    """The group check's estimate and uncertainty, grown along the chain on demand: each new
    vertex starts where its step from the current estimate of the one before puts it."""

    def __init__(self, links: Sequence[GraphEdge], count: int, graph: GraphConfig) -> None:
        self._steps: dict[int, list[GraphEdge]] = {}
        for e in links:
            self._steps.setdefault(e.b, []).append(e)
        self._count = count
        self.estimate = RunningEstimate(np.zeros(3), graph)
        self.uncertainty = UncertaintyGraph()

    def to(self, end: int) -> None:
        """Adds the vertices before ``end`` and their steps. They wait for the next update
        (the next loop closed): a chain's new end has no loop to move it, so where each step
        puts a vertex is already the estimate's answer."""
        end = min(end, self._count)
        have = len(self.estimate)
        if have >= end:
            return
        last = self.estimate.poses[have - 1]
        for k in range(have, end):
            steps = self._steps[k]
            last = se2.compose(last, steps[0].measurement)
            self.estimate.add_keyframe(last)
            for step in steps:
                self.estimate.add_edge(step)
                self.uncertainty.add(step)


def rescue(
    loop_of: Callable[[int], Loop],
    failed: Sequence[int],
    held: Sequence[int],
    poses: NDArray[np.float64],
    uncertainty: UncertaintyGraph,
    gate: float,
    support: tuple[int, int],
) -> dict[int, int]:
    """The failed loops (``loop_of`` an edge index) that at least ``support[0]`` held loops
    near them agree with.

    Near means both ends within ``support[1]`` vertices, so the cycle between them runs
    through a short stretch of the chain and the test says something: an injected loop
    between two places 5 m apart meets no held loop whose cycle with it closes, since any
    loop near both its ends says the places are where they are.
    """
    need, span = support
    if need <= 0 or not failed or not held:
        return {}
    others = [loop_of(j) for j in held]
    a_of = np.array([o.a for o in others])
    b_of = np.array([o.b for o in others])
    nearby: dict[int, NDArray[np.int64]] = {}
    for i in failed:
        one = loop_of(i)
        near = np.flatnonzero((np.abs(a_of - one.a) <= span) & (np.abs(b_of - one.b) <= span))
        near = near[[held[int(k)] != i for k in near]]
        if len(near) >= need:
            nearby[i] = near
    # Only the loops with enough held loops near them are tested: the projection is asked
    # for their ends alone (a fifth of the failed loops' on Killian Court).
    ends = sorted({x for i in nearby for x in (loop_of(i).a, loop_of(i).b)})
    rel = dict(zip(ends, uncertainty.relative(ends, len(poses)), strict=True))
    out: dict[int, int] = {}
    for i, near in nearby.items():
        one = loop_of(i)
        agree = int(np.sum(cycle_chi2s(one, [others[int(k)] for k in near], poses, rel) <= gate))
        if agree >= need:
            out[i] = int(agree)
    return out
