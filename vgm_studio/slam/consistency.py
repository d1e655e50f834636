"""Group consistency of loop closures: pairwise consistency maximisation (PCM).

A validator judges each loop alone, from the two scans; it cannot see that a loop between two
identical doors one door apart is wrong. Mangelson et al. (2018, "Pairwise Consistency
Maximization for Robust Multi-robot Map Merging") test loops in pairs instead: two loops
(a₁→b₁, z₁) and (a₂→b₂, z₂) agree when the cycle they close with the graph between their
ends, z₁ ∘ (b₁→b₂) ∘ z₂⁻¹ ∘ (a₂→a₁), is the identity within its covariance (a χ²(3) gate on the
Mahalanobis distance), and the largest set of loops that all agree pairwise (the maximum
clique of the consistency graph) is kept.

Here the chains between the ends come from the running estimate, their covariance from the
graph's Dijkstra projection (``uncertainty``). The estimate itself is one more member of the
group, tested against each loop the same way (the cycle a→b through the loop and back through
the graph), and it votes twice. Within its gate it counts as a few loops; within the gate
of its σ widened ``overconfidence`` times it counts as many (``estimate_weight``). So a loop
that disagrees with a sure estimate is rejected even when it is the only one; a loop the
widened gate still cannot explain (a corridor matched back to front, tens of σ off) is
rejected however many agree; and a run of agreeing loops just past the gate outvotes the
estimate. The graph's σ comes from the matchers' covariances, and a match that is wrong at a
tight covariance leaves the estimate surer than it is: on CSAIL a validator that passed
other early loops left a revisit of 12 right loops (p ≥ 0.8) 3.5 σ off the estimate, and
the map 2.2 m off. The price: where the estimate has itself drifted far, a run of aliases can
lie within the widened gate too (the infinite corridor with a validator that never saw it:
five loops matched back to front, 74° off an estimate of σ 18°, came in).

A loop that moves the map by more than the scan matchers can have drifted (judged with the
drift's narrower covariance), and any loop from place recognition, is a surprise; a long
corridor or a row of identical rooms can produce one convincing but wrong match, so a surprise
is kept only in a group of more than ``min_support`` agreeing loops: the temporal-consistency
check of place recognition systems (e.g. ORB-SLAM's three consecutive consistent loop
candidates, Mur-Artal et al. 2015).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

import networkx as nx
import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.core.cliques import largest_clique_size
from vgm_studio.slam.config import ConsistencyConfig
from vgm_studio.slam.uncertainty import Relative, UncertaintyGraph, chi2_gate

# The estimate's two votes: sure of what its widened gate holds, likely of what its gate holds.
_SURE, _LIKELY = -1, -2
_ESTIMATE = (_SURE, _LIKELY)
_MAX_CLIQUES = 20_000


@dataclass(frozen=True)
class Loop:
    """A loop closure to check: pose of b in a's frame and its covariance."""

    a: int
    b: int
    measurement: NDArray[np.float64]
    covariance: NDArray[np.float64]
    surprise: bool = False
    """Needs support whatever the estimate says: proposed by place recognition, which never
    read the estimate, or kept on the overlap of local maps rather than by the validator."""


def consistent(
    loops: Sequence[Loop],
    poses: NDArray[np.float64],
    graph: UncertaintyGraph,
    config: ConsistencyConfig | None = None,
    drift: UncertaintyGraph | None = None,
) -> NDArray[np.bool_]:
    """Which loops belong to the largest mutually consistent group (with the estimate).

    Args:
        loops: Loops the validator kept, not yet in the graph.
        poses: (K, 3) the running estimate.
        graph: The edges already in the graph, for the chains' covariances.
        config: Gate, vote and support.
        drift: The edges as the scan matcher's drift sees them (narrower than the graph's
            floors). A loop that this view of the estimate cannot explain moves the map by
            more than the matchers drift: it needs ``config.min_support`` agreeing loops.
    """
    config = config or ConsistencyConfig()
    if not loops:
        return np.zeros(0, dtype=bool)
    ends = sorted({x for loop in loops for x in (loop.a, loop.b)})
    rel = dict(zip(ends, graph.relative(ends, len(poses)), strict=True))
    gate = chi2_gate(config.probability, 3)
    votes = nx.Graph()
    # A loop weighs 2 and a vote of w loops 2w + 1: a group of loops can never tie with the
    # estimate, which would leave the choice to whichever clique networkx happens to find.
    votes.add_node(_SURE, weight=2 * config.estimate_weight + 1)
    votes.add_node(_LIKELY, weight=2 * config.likely_weight + 1)
    votes.add_edge(_SURE, _LIKELY, chi2=0.0)
    for i, loop in enumerate(loops):
        votes.add_node(i, weight=2)
        fit = _fits_estimate(loop, poses, rel[loop.a])
        if fit <= gate * config.overconfidence**2:
            votes.add_edge(_SURE, i, chi2=fit)
        if fit <= gate:
            votes.add_edge(_LIKELY, i, chi2=fit)
    for i in range(len(loops)):
        cycles = cycle_chi2s(loops[i], loops[i + 1 :], poses, rel)
        for j in np.flatnonzero(cycles <= gate):
            votes.add_edge(i, i + 1 + int(j), chi2=float(cycles[j]))
    members = {i for i in _heaviest(votes) if i not in _ESTIMATE}
    if drift is not None and members:
        members -= _unsupported(loops, members, votes, poses, drift, gate, config)
    return np.array([i in members for i in range(len(loops))], dtype=bool)


def _heaviest(votes: nx.Graph) -> list[int]:
    """The clique of most weight; among equally heavy ones, the one whose members agree best
    (least χ² summed over its pairs).

    Equal weights are common: a revisit's loop can agree both with its right neighbour and
    with one slid along the corridor, which disagree with each other. Which of the two groups
    networkx returns then depends on node order. On CSAIL 114→321 agreed with the right
    116→323 at χ² 1.6 and with 116→325, 1.7 m along, at 11.3 (the gate: 11.34).
    """
    best: list[int] = []
    key = (-math.inf, 0.0)
    for count, clique in enumerate(nx.find_cliques(votes)):
        if count == _MAX_CLIQUES:
            # A consistency graph this tangled has no clear group; leave it to the exact
            # search rather than enumerate every maximal clique.
            return list(nx.max_weight_clique(votes, weight="weight")[0])
        weight = sum(votes.nodes[i]["weight"] for i in clique)
        if weight < key[0]:
            continue
        spread = sum(votes.edges[i, j]["chi2"] for i, j in combinations(clique, 2))
        if (weight, -spread) > key:
            best, key = clique, (weight, -spread)
    return best


def _unsupported(
    loops: Sequence[Loop],
    members: set[int],
    votes: nx.Graph,
    poses: NDArray[np.float64],
    drift: UncertaintyGraph,
    gate: float,
    config: ConsistencyConfig,
) -> set[int]:
    """The surprises of the chosen group that lack support: all of them where a rival group
    stands (``_rivalled``), else each one with no more than ``min_support`` agreeing members
    (itself included) near it at both ends.

    Near means the drift puts the two ends within ``support_sigma`` of each other (one σ): two
    loops whose ends lie far apart in an uncertain graph pass the cycle test only because the
    chain between them could bend either way, which says nothing. On CSAIL one alias 10.7 m
    off joined two right loops 90 keyframes away and stayed in.
    """
    # The drift's projection costs a Dijkstra pass per end: the targets' for every member,
    # every other end only where there are surprises to judge.
    targets = sorted({loops[i].a for i in members})
    rel = dict(zip(targets, drift.relative(targets, len(poses)), strict=True))
    surprises = {
        i
        for i in members
        if loops[i].surprise or _fits_estimate(loops[i], poses, rel[loops[i].a]) > gate
    }
    if not surprises:
        return set()
    later = sorted({x for loop in loops for x in (loop.a, loop.b)} - rel.keys())
    rel.update(zip(later, drift.relative(later, len(poses)), strict=True))
    limit = config.support_sigma**2

    def near(one: Loop, two: Loop) -> bool:
        var = max(rel[one.a].position_var[two.a], rel[one.b].position_var[two.b])
        return bool(var <= limit)

    supports = nx.Graph()
    supports.add_nodes_from(range(len(loops)))
    supports.add_edges_from(
        (i, j)
        for i, j in votes.edges
        if i not in _ESTIMATE and j not in _ESTIMATE and near(loops[i], loops[j])
    )
    if _rivalled(supports, members, config.min_support):
        return surprises
    return {
        i
        for i in surprises
        if 1 + sum(j in members for j in supports.neighbors(i)) <= config.min_support
    }


def _rivalled(supports: nx.Graph, members: set[int], support: int) -> bool:
    """Whether the loops left out hold a group that would pass on its own (more than
    ``support`` loops that support one another) and is at least half as large as the
    largest such group among the chosen; if so, the chosen group's surprises (the members
    that move the map by more than the drift) go out.

    Along a periodic corridor, one stretch matched one period along yields as long a run of
    agreeing loops as a revisit does, and so does a second period: the infinite corridor
    once offered three groups of three, 17.6, 24.3 and 24.8 m off, and the check took one
    of them. Where the loops of a block tell two stories about equally, neither is taken;
    a revisit goes on agreeing with itself in the next blocks.

    Groups are counted by support, not by the cycle test alone: far loops in an uncertain
    graph agree with anything (CSAIL keyframes 320–325: two lone wrong place loops, 90
    keyframes apart, made a "rival" to two right loops 2 keyframes apart, and both right
    ones went out with the alias the chosen group had taken in).
    """
    rest = supports.subgraph(n for n in supports if n not in members)
    if rest.number_of_nodes() <= support:
        return False
    rival = _largest_group(rest)
    chosen = _largest_group(supports.subgraph(members))
    return rival > support and 2 * rival >= chosen


def _largest_group(graph: nx.Graph) -> int:
    return largest_clique_size(graph.nodes, graph.edges)


def _variances(cov: NDArray[np.float64]) -> tuple[float, float]:
    return float(cov[0, 0] + cov[1, 1]) / 2.0, float(cov[2, 2])


def _mahalanobis(
    error: NDArray[np.float64],
    position_var: float | NDArray[np.float64],
    heading_var: float | NDArray[np.float64],
) -> NDArray[np.float64]:
    """Squared Mahalanobis distance of (…, 3) errors, the position's variance isotropic."""
    e = np.asarray(error, dtype=np.float64)
    position = (e[..., 0] ** 2 + e[..., 1] ** 2) / position_var
    return np.asarray(position + e[..., 2] ** 2 / heading_var)


def _fits_estimate(loop: Loop, poses: NDArray[np.float64], rel: Relative) -> float:
    """Squared Mahalanobis distance of the loop from the estimate's a→b."""
    vt, vr = _variances(loop.covariance)
    error = se2.between(se2.between(poses[loop.a], poses[loop.b]), loop.measurement)
    return float(_mahalanobis(error, vt + rel.position_var[loop.b], vr + rel.heading_var[loop.b]))


def cycle_chi2(one: Loop, two: Loop, poses: NDArray[np.float64], rel: dict[int, Relative]) -> float:
    """Squared Mahalanobis distance of the cycle two loops close with the graph; ``rel``
    holds the graph's uncertainty seen from ``one``'s two ends."""
    return float(cycle_chi2s(one, [two], poses, rel)[0])


def cycle_chi2s(
    one: Loop, others: Sequence[Loop], poses: NDArray[np.float64], rel: dict[int, Relative]
) -> NDArray[np.float64]:
    """``cycle_chi2`` of ``one`` with each of ``others``, at once (a block's pairs number
    thousands on a large building)."""
    if not others:
        return np.zeros(0)
    a2 = np.array([two.a for two in others])
    b2 = np.array([two.b for two in others])
    chain_b = se2.between(poses[one.b], poses[b2])
    chain_a = se2.between(poses[one.a], poses[a2])
    # b₂ in a₁'s frame, once through loop one, once through loop two.
    via_one = se2.compose(one.measurement, chain_b)
    via_two = se2.compose(chain_a, np.array([two.measurement for two in others]))
    error = se2.between(via_one, via_two)
    vt1, vr1 = _variances(one.covariance)
    cov2 = np.array([two.covariance for two in others])
    vt2, vr2 = (cov2[:, 0, 0] + cov2[:, 1, 1]) / 2.0, cov2[:, 2, 2]
    # A heading error of a loop swings the chain after it by its length.
    lever = chain_b[:, 0] ** 2 + chain_b[:, 1] ** 2
    ra, rb = rel[one.a], rel[one.b]
    position = vt1 + vt2 + vr1 * lever + rb.position_var[b2] + ra.position_var[a2]
    heading = vr1 + vr2 + rb.heading_var[b2] + ra.heading_var[a2]
    return _mahalanobis(error, position, heading)
