"""The loop search's parts with real numbers: relations from reference poses, the graph's
relative uncertainty, the window search and the group-consistency check."""

from __future__ import annotations

import math
from functools import partial

import networkx as nx
import numpy as np
import pytest
from scipy.stats import chi2

from vgm_studio.core import se2
from vgm_studio.graph.metrics import RelationSampling, reference_relations, relation_errors
from vgm_studio.graph.pose_graph import GraphEdge
from vgm_studio.slam.config import ConsistencyConfig, FrontEndConfig
from vgm_studio.slam.consistency import Loop, consistent, cycle_chi2
from vgm_studio.slam.loop_search import unclosed_candidates, window_candidates
from vgm_studio.slam.uncertainty import UncertaintyGraph

STEP_COV = np.diag([0.005**2, 0.005**2, math.radians(0.03) ** 2])
LOOP_COV = np.diag([0.02**2, 0.02**2, math.radians(0.5) ** 2])


def out_and_back(length: float = 100.0, step: float = 0.5) -> np.ndarray:
    """Down a straight corridor and back along the other side, 1 m to the left."""
    n = int(length / step)
    out = np.column_stack([np.arange(n) * step, np.zeros(n), np.zeros(n)])
    back = np.column_stack([out[::-1, 0], np.ones(n), np.full(n, math.pi)])
    return np.vstack([out, back])


def racetrack(length: float = 100.0, width: float = 2.0, step: float = 0.5) -> np.ndarray:
    """Once round a long thin rectangle, then a few metres of the first side again."""
    legs = [((0, 0), (length, 0)), ((length, 0), (length, width)), ((length, width), (0, width))]
    legs += [((0, width), (0, 0)), ((0, 0), (3.0, 0))]
    out = []
    for (x0, y0), (x1, y1) in legs:
        n = max(1, round(math.dist((x0, y0), (x1, y1)) / step))
        heading = math.atan2(y1 - y0, x1 - x0)
        for t in np.arange(n) / n:
            out.append((x0 + t * (x1 - x0), y0 + t * (y1 - y0), heading))
    return np.array(out)


def chain(poses: np.ndarray, cov: np.ndarray = STEP_COV) -> UncertaintyGraph:
    """Consecutive poses joined by edges of covariance ``cov``, or ``cov[i - 1]`` for the
    edge into pose i where a stack of covariances is given."""
    covs = cov if cov.ndim == 3 else [cov] * (len(poses) - 1)
    graph = UncertaintyGraph()
    for i in range(1, len(poses)):
        graph.add(GraphEdge(i - 1, i, se2.between(poses[i - 1], poses[i]), covs[i - 1], True))
    return graph


def test_reference_relations_join_neighbours_and_revisits_and_score_the_reference_as_exact():
    truth = out_and_back(20.0, 0.1)
    reference: list[np.ndarray | None] = list(truth)
    reference[5] = None  # a scan without a reference pose takes part in no relation
    relations = reference_relations(reference, RelationSampling(seed=3))
    pairs = [(r.a, r.b) for r in relations]
    again = reference_relations(reference, RelationSampling(seed=3))
    assert pairs == [(r.a, r.b) for r in again]
    assert pairs != [(r.a, r.b) for r in reference_relations(reference, RelationSampling(seed=4))]
    assert all(5 not in p and a < b for p in pairs for a, b in [p])
    gaps = [math.dist(truth[r.a, :2], truth[r.b, :2]) for r in relations]
    sequential = sum(g < 0.65 for g in gaps)
    # Places half a metre apart along 40 m: about 80 sequential pairs, as many revisits
    # (the way back passes 1 m from the way out), none farther than 3 m apart.
    assert 70 <= sequential <= 85 and len(relations) >= 2 * sequential - 2
    assert max(gaps) <= 3.0 and sum(abs(r.b - r.a) > 100 for r in relations) > 30
    assert relation_errors(truth, relations).trans_mean < 1e-12
    bent = truth.copy()
    bent[200:] = se2.compose(
        se2.compose(truth[199], [0, 0, 0.05]), se2.between(truth[199], truth[200:])
    )
    assert relation_errors(bent, relations).trans_mean > 0.01
    assert reference_relations([None, truth[0]]) == []


def test_relative_uncertainty_grows_along_a_chain_and_a_loop_shrinks_it():
    poses = out_and_back()
    graph = chain(poses)
    last = len(poses) - 1
    (rel,) = graph.relative([last], len(poses))
    assert rel.position_var[last] == 0.0
    # Monotone along the chain back to the start, metres of σ after 200 m.
    assert np.all(np.diff(rel.position_var[::-1]) >= 0)
    assert 0.5 < math.sqrt(rel.position_var[0]) < 5.0
    graph.add(GraphEdge(0, last, se2.between(poses[0], poses[last]), LOOP_COV))
    (closed,) = graph.relative([last], len(poses))
    assert closed.position_var[0] < 0.01 * rel.position_var[0]
    assert closed.heading_var[0] < rel.heading_var[0]


def test_window_search_widens_after_a_long_corridor_and_gates_by_mahalanobis():
    poses = racetrack()
    graph = chain(poses)
    config = FrontEndConfig()
    count = len(poses)
    # 200 m round, the estimate has drifted 2 m along the first side: the window must be
    # metres wide to match the start again.
    drifted = poses.copy()
    drifted[:, 0] += np.linspace(0, 2.0, count)
    block = range(count - 5, count)
    found = window_candidates(block, drifted, graph, config)
    assert found and all(c.source == "window" for c in found)
    assert {c.a for c in found} <= set(range(0, 12))
    assert all(c.linear == config.window_linear[1] for c in found)
    # Clamped smaller than the drift: the window may miss the place, so place recognition
    # is asked too (``covers`` is what the front end reads).
    assert not any(c.covers for c in found)
    # A scan matcher's heading drift over 200 m is about a degree: the narrowest turn.
    assert all(
        c.angular == pytest.approx(math.radians(config.window_angular_deg[0])) for c in found
    )
    per_keyframe = np.bincount([c.b for c in found])
    assert per_keyframe.max() <= config.loops_per_keyframe
    # Once the ends are tied, the same keyframes get the smallest window, and a place 6 m
    # off to the side in the estimate is no longer a candidate.
    graph.add(GraphEdge(0, count - 1, se2.between(poses[0], poses[-1]), LOOP_COV))
    tight = window_candidates(block, poses, graph, config)
    assert tight and all(c.linear == config.window_linear[0] for c in tight)
    assert all(c.covers for c in tight)
    far = poses.copy()
    far[count - 5 :, 1] += 6.0
    assert window_candidates(block, far, graph, config) == []
    assert window_candidates(range(1, 5), poses, graph, config) == []


def ring(count: int = 120, radius: float = 10.0) -> np.ndarray:
    angle = np.linspace(0, 2 * math.pi, count, endpoint=False)
    return np.column_stack(
        [radius * np.cos(angle), radius * np.sin(angle), se2.wrap_angle(angle + math.pi / 2)]
    )


def test_consistency_keeps_agreeing_loops_and_rejects_aliased_ones():
    truth = ring()
    rng = np.random.default_rng(4)
    graph = chain(truth, LOOP_COV)  # the graph's own floors, as the front end checks with
    # The estimate has drifted (rigidly, after keyframe 60): the check must not rely on it.
    estimate = truth.copy()
    estimate[60:] = se2.compose([0.3, -0.2, 0.01], truth[60:])
    loops = []
    for a in range(0, 30, 3):
        b = a + 90
        z = se2.between(truth[a], truth[b]) + rng.normal(0, [0.01, 0.01, 0.002])
        loops.append(Loop(a, b, z, LOOP_COV))
    aliased = []
    for a in (4, 11, 19):
        b = a + 90
        # One door along: a perfect-looking match two metres off.
        z = se2.compose(se2.between(truth[a], truth[b]), [2.0, 0.0, 0.0])
        aliased.append(Loop(a, b, z, LOOP_COV))
    flags = consistent(loops + aliased, estimate, graph, ConsistencyConfig())
    assert flags[: len(loops)].all()
    assert not flags[len(loops) :].any()
    # Alone, a loop far from a confident estimate is rejected; no loops, no decisions.
    sure = chain(truth, STEP_COV * 1e-4)
    assert not consistent([aliased[0]], truth, sure)[0]
    assert consistent([loops[0]], truth, sure)[0]
    assert consistent([], truth, sure).shape == (0,)


@pytest.mark.parametrize("weight", [1, 3])
def test_a_group_of_agreeing_loops_outvotes_a_drifted_estimate(weight):
    truth = ring()
    graph = chain(truth, STEP_COV * 1e-4)  # the graph (wrongly) believes its odometry
    estimate = truth.copy()
    estimate[60:, :2] += 1.5
    loops = [
        Loop(a, a + 90, se2.between(truth[a], truth[a + 90]), LOOP_COV) for a in range(0, 30, 2)
    ]
    flags = consistent(loops, estimate, graph, ConsistencyConfig(estimate_weight=weight))
    assert flags.all()


def _drifted_by(truth: np.ndarray, graph: UncertaintyGraph, fit: float) -> np.ndarray:
    """The estimate moved rigidly after keyframe 60 so that a loop a → a + 90 of ``truth``
    lies ``fit`` (squared Mahalanobis, the graph's σ and LOOP_COV's) from it."""
    rel = graph.relative([0], len(truth))[0]
    sigma = math.sqrt(rel.position_var[90] + (LOOP_COV[0, 0] + LOOP_COV[1, 1]) / 2)
    estimate = truth.copy()
    estimate[60:, 0] += math.sqrt(fit) * sigma
    return estimate


def test_a_run_of_loops_just_past_the_estimate_gate_outvotes_it_and_a_gross_one_never():
    truth = ring()
    graph = chain(truth, STEP_COV * 100)  # the same σ at every loop of the ring
    config = ConsistencyConfig()
    gate = float(chi2.ppf(config.probability, 3))
    loops = [
        Loop(a, a + 90, se2.between(truth[a], truth[a + 90]), LOOP_COV) for a in range(0, 24, 2)
    ]
    just_past = _drifted_by(truth, graph, 2 * gate)  # within the widened gate (4x)
    assert consistent(loops, just_past, graph, config).all()
    few = loops[: config.likely_weight]
    assert not consistent(few, just_past, graph, config).any()
    assert consistent(loops[: config.likely_weight + 1], just_past, graph, config).all()
    # A corridor matched back to front lies tens of σ off: no group outvotes that.
    gross = _drifted_by(truth, graph, 6 * gate)
    assert not consistent(loops, gross, graph, config).any()
    # With no doubt allowed, the estimate vetoes the run just past its gate too.
    strict = ConsistencyConfig(overconfidence=1.0)
    assert not consistent(loops, just_past, graph, strict).any()


def test_a_loop_that_moves_the_map_past_the_drift_needs_a_group_that_agrees():
    truth = ring()
    wide = chain(truth, LOOP_COV * 25)  # the graph's floors: it would let either through
    drift = chain(truth, STEP_COV)  # the scan matchers' drift: 1.5 m is a surprise
    estimate = truth.copy()
    estimate[60:, :2] += 1.5
    loops = [
        Loop(a, a + 90, se2.between(truth[a], truth[a + 90]), LOOP_COV) for a in range(0, 8, 2)
    ]
    config = ConsistencyConfig(min_support=2)
    # One convincing match alone: an alias as far as the check can tell.
    assert not consistent(loops[:1], estimate, wide, config, drift=drift)[0]
    assert not consistent(loops[:2], estimate, wide, config, drift=drift).any()
    # Three or more that agree: a revisit after drift, kept.
    assert consistent(loops[:3], estimate, wide, config, drift=drift).all()
    assert consistent(loops, estimate, wide, config, drift=drift).all()
    # Without the drift view, or with no support asked, one is enough.
    assert consistent(loops[:1], estimate, wide, config)[0]
    no_support = ConsistencyConfig(min_support=0)
    assert consistent(loops[:1], estimate, wide, no_support, drift=drift)[0]
    # A loop the drift explains needs no support, unless place recognition proposed it.
    assert consistent(loops[:1], truth, wide, config, drift=drift)[0]
    place = [Loop(x.a, x.b, x.measurement, x.covariance, surprise=True) for x in loops]
    assert not consistent(place[:1], truth, wide, config, drift=drift)[0]
    assert consistent(place[:3], truth, wide, config, drift=drift).all()


def test_two_groups_of_surprises_that_tell_two_stories_are_both_left_out():
    """A periodic corridor: keyframes matched one period along agree with one another as well
    as a true revisit's loops do. The ring is symmetric, so loops that claim b lies from
    a + 6 where it truly lies from a are a consistent group, and a wrong one."""
    truth = ring()
    wide = chain(truth, LOOP_COV * 25)
    drift = chain(truth, STEP_COV)
    estimate = truth.copy()
    estimate[60:, :2] += 1.5
    config = ConsistencyConfig(min_support=2)

    def place(a: int, claimed: int) -> Loop:
        return Loop(claimed, a + 90, se2.between(truth[a], truth[a + 90]), LOOP_COV, surprise=True)

    right = [place(a, a) for a in range(0, 14, 2)]  # seven
    alias = [place(a, a + 6) for a in (1, 3, 5)]  # three, one period along
    assert consistent(right[:3], estimate, wide, config, drift=drift).all()
    assert consistent(alias, estimate, wide, config, drift=drift).all()  # alone, it would pass
    # Three against three: neither story is taken.
    assert not consistent(right[:3] + alias, estimate, wide, config, drift=drift).any()
    # Seven against three: the revisit's run is kept, the aliases are not.
    flags = consistent(right + alias, estimate, wide, config, drift=drift)
    assert flags[: len(right)].all() and not flags[len(right) :].any()
    # Two aliases would not pass on their own: no rival.
    assert consistent(right[:3] + alias[:2], estimate, wide, config, drift=drift)[:3].all()


def _lost_ring() -> tuple[np.ndarray, UncertaintyGraph, UncertaintyGraph, np.ndarray]:
    """A ring whose odometry was lost over its first 20 steps: the truth, the graph's wide
    view, the drift's view (wide over the lost stretch) and an estimate that puts keyframes
    from 60 on 1.5 m off."""
    truth = ring()
    wide = chain(truth, LOOP_COV * 25)
    lost = np.diag([0.03**2, 0.03**2, math.radians(2.0) ** 2])
    drift = chain(truth, np.array([lost if i <= 20 else STEP_COV for i in range(1, len(truth))]))
    estimate = truth.copy()
    estimate[60:, :2] += 1.5
    return truth, wide, drift, estimate


def _surprise(truth: np.ndarray, a: int, b: int, off: float = 0.0) -> Loop:
    """A place loop a → b that claims b lies ``off`` metres further along its heading."""
    z = se2.compose(se2.between(truth[a], truth[b]), [off, 0.0, 0.0])
    return Loop(a, b, z, LOOP_COV, surprise=True)


def test_support_counts_only_loops_whose_ends_the_drift_holds_close():
    """CSAIL: an alias 10.7 m off joined two right loops whose targets lay 90 keyframes from
    its own, across steps where the odometry was lost. The cycle test passed because that
    chain could bend either way; it says nothing, so such a loop is no support."""
    truth, wide, drift, estimate = _lost_ring()
    assert drift.relative([0], len(truth))[0].position_var[20] > 0.5**2
    config = ConsistencyConfig(min_support=1, support_sigma=0.5)

    place = partial(_surprise, truth)

    right = [place(0, 90), place(2, 92)]
    alias = place(20, 94, off=3.0)  # a door along, across the stretch the odometry lost
    # Alone, a place loop is not enough; two neighbours that agree are.
    assert not consistent(right[:1], estimate, wide, config, drift=drift)[0]
    assert consistent(right, estimate, wide, config, drift=drift).all()
    flags = consistent([*right, alias], estimate, wide, config, drift=drift)
    assert flags[:2].all() and not flags[2]
    # Counting far loops as support, the alias would ride in with them.
    anywhere = ConsistencyConfig(min_support=1, support_sigma=math.inf)
    assert consistent([*right, alias], estimate, wide, anywhere, drift=drift).all()


def test_keyframes_passed_the_other_way_get_their_own_slot_and_take_none_of_the_others():
    """Out along a corridor, back along its other side, out again near the back lane: the
    back lane lies nearest but faced the other way. It must not crowd out the same-way pass,
    and the revisit the other way is still proposed."""
    out_back = out_and_back(length=30.0)
    again = out_back[:60].copy()
    again[:, 1] = 0.9
    poses = np.vstack([out_back, again])
    graph = chain(poses)
    block = range(len(poses) - 30, len(poses) - 25)
    config = FrontEndConfig(loops_per_keyframe=2, turned_loops_per_keyframe=1)
    found = window_candidates(block, poses, graph, config)
    out_leg, back_leg = range(0, 60), range(60, 120)
    for b in block:
        mine = [c.a for c in found if c.b == b]
        assert sum(a in out_leg for a in mine) == 2
        assert sum(a in back_leg for a in mine) == 1
        # The same-way candidates are the nearest of the out leg, where b is again.
        assert all(abs(poses[a, 0] - poses[b, 0]) <= 0.5 for a in mine if a in out_leg)
    same_way_only = FrontEndConfig(loops_per_keyframe=2, turned_loops_per_keyframe=0)
    assert {c.a for c in window_candidates(block, poses, graph, same_way_only)} <= set(out_leg)


def test_a_rival_group_must_hold_together_too():
    """CSAIL keyframes 320–325: two lone wrong place loops, their targets far apart across a
    lost stretch, agreed in the cycle test only because the chain between them could bend
    either way. Counted as a rival group, they took the two right loops out with them; a
    rival counts only loops that support one another, as a surprise's support does."""
    truth, wide, drift, estimate = _lost_ring()
    config = ConsistencyConfig(min_support=1, support_sigma=0.5)

    place = partial(_surprise, truth)

    right = [place(30, 90), place(32, 92), place(34, 94)]
    wrong = [place(2, 91, off=-9.0), place(20, 93, off=-9.0)]  # doors along
    flags = consistent([*right, *wrong], estimate, wide, config, drift=drift)
    assert flags[:3].all() and not flags[3:].any(), flags
    # Two wrong loops that do hold together (a run matched six keyframes along) are a
    # rival: neither story is taken.
    close = [
        Loop(a + 6, a + 61, se2.between(truth[a], truth[a + 61]), LOOP_COV, surprise=True)
        for a in (30, 32)
    ]
    assert not consistent([*right, *close], estimate, wide, config, drift=drift).any()


@pytest.mark.parametrize("slid_first", [False, True])
def test_of_two_equally_heavy_groups_the_one_that_agrees_best_is_kept(slid_first):
    """A revisit's loop agrees with its right neighbour and with a neighbour slid along the
    corridor (the chain between their ends is loose enough for both), and those two
    disagree: two groups of the same weight. CSAIL's 114→321 with 116→323 and 116→325."""
    truth = ring()
    graph = chain(truth, LOOP_COV * 25)  # loose: the estimate explains all three loops

    def loop(a: int, slide: float = 0.0) -> Loop:
        z = se2.compose(se2.between(truth[a], truth[a + 90]), [slide, 0.0, 0.0])
        return Loop(a, a + 90, z, LOOP_COV)

    first, right, slid = loop(10), loop(12), loop(12, 0.3)
    ends = [10, 12, 100, 102]
    rel = dict(zip(ends, graph.relative(ends, len(truth)), strict=True))
    gate = float(chi2.ppf(ConsistencyConfig().probability, 3))
    assert cycle_chi2(first, slid, truth, rel) < gate < cycle_chi2(right, slid, truth, rel)
    # networkx would take whichever group its node order finds first.
    names = ("first", "slid", "right") if slid_first else ("first", "right", "slid")
    loops = [{"first": first, "right": right, "slid": slid}[n] for n in names]
    kept = dict(zip(names, consistent(loops, truth, graph).tolist(), strict=True))
    assert kept == {"first": True, "right": True, "slid": False}


def test_a_tangle_of_groups_falls_back_to_the_exact_search(monkeypatch):
    """The complement of disjoint triangles has 3^(n/3) maximal cliques: past the cap the
    enumeration stops, and the exact search still finds the heaviest, enumerated last."""
    from vgm_studio.slam import consistency

    tangle = nx.complement(nx.disjoint_union_all([nx.complete_graph(3)] * 4))
    cliques = list(nx.find_cliques(tangle))
    assert len(cliques) == 81
    heaviest = sorted(cliques[-1])
    nx.set_node_attributes(tangle, {n: 3 if n in heaviest else 2 for n in tangle}, "weight")
    nx.set_edge_attributes(tangle, 1.0, "chi2")
    for cap in (10, 1000):
        monkeypatch.setattr(consistency, "_MAX_CLIQUES", cap)
        assert sorted(consistency._heaviest(tangle)) == heaviest


def test_the_final_sweep_searches_only_revisits_left_unclosed():
    """Down a corridor and back along it: the way back passes every keyframe of the way out.
    With the loops of the back half's first stretch kept, the sweep proposes candidates on
    the rest of the way back only, none joining the neighbourhoods of a kept loop."""
    poses = out_and_back(length=50.0)
    graph = chain(poses)
    config = FrontEndConfig()
    count, span = len(poses), config.submap_keyframes
    every = window_candidates(range(count), poses, graph, config)
    assert every  # the way back is a revisit throughout
    nothing_closed = np.zeros((0, 2), np.int64)
    pairs = [(c.a, c.b) for c in every]
    assert [(c.a, c.b) for c in unclosed_candidates(nothing_closed, poses, graph, config)] == pairs
    closed = np.array([(count - 1 - b, b) for b in range(count // 2, count // 2 + 40, 4)])
    swept = unclosed_candidates(closed, poses, graph, config)
    assert swept and len(swept) < len(every)
    assert {(c.a, c.b) for c in swept} <= set(pairs)
    for c in swept:
        assert np.abs(closed[:, 1] - c.b).min() > span  # b is far from every kept loop's end
    # Every keyframe of the way back that no kept loop reaches is searched again.
    lonely = [b for b in range(count) if np.abs(closed[:, 1] - b).min() > span]
    assert {c.b for c in swept} == {c.b for c in every if c.b in lonely}
    # Where the estimate has not moved since a keyframe's online search, the sweep would
    # repeat it: nothing to search. Where it has, by more than the smallest window, it does.
    assert (
        unclosed_candidates(
            nothing_closed, poses, graph, config, dict.fromkeys(range(count), poses)
        )
        == []
    )
    shifted = poses.copy()
    shifted[count // 2 :, 0] += 2 * config.window_linear[0]
    then = dict.fromkeys(range(count), shifted)
    again = unclosed_candidates(nothing_closed, poses, graph, config, then)
    assert [(c.a, c.b) for c in again] == pairs


def test_path_sums_are_each_nodes_sums_over_its_path_to_the_root():
    from vgm_studio.slam.uncertainty import _path_sums

    rng = np.random.default_rng(4)
    n = 3000
    # A random forest: each node hangs off an earlier one (or is a root), as a shortest-path
    # tree does, listed out of order; each edge's (translational, rotational, length) row is
    # found by its key among the sorted keys, one past row 0 of zeros.
    parent = np.array(
        [k if k == 0 or rng.random() < 0.01 else rng.integers(0, k) for k in range(n)]
    )
    shuffle = rng.permutation(n)
    parent = np.argsort(shuffle)[parent[shuffle]]
    child = np.flatnonzero(parent != np.arange(n))
    keys = np.minimum(parent[child], child) * n + np.maximum(parent[child], child)
    order = np.argsort(keys)
    rows = rng.uniform(0.0, 1.0, (len(child), 3))
    values = np.vstack([np.zeros((1, 3)), rows[order]])
    got = _path_sums(parent, keys[order], values)
    own = dict(zip(child.tolist(), rows, strict=True))
    for v in range(n):
        total, k = np.zeros(3), v
        path = []
        while parent[k] != k:
            path.append(k)
            k = int(parent[k])
        for k in reversed(path):  # from the root down, as the tree is walked
            total = total + own[k]
        assert np.array_equal(got[v], total), v
    assert np.count_nonzero(got[:, 2] > 5.0) > 100  # long paths were summed
    # Compiled code checks no bounds: what is not a forest, or an edge not among the keys,
    # raises instead of reading or writing past the arrays.
    zeros = np.zeros((2, 3))
    for bad_parent, bad_keys in [([1, 0, 2], [1]), ([0, 5], [1]), ([0, 0, 0], [1])]:
        with pytest.raises(ValueError):
            _path_sums(np.array(bad_parent), np.array(bad_keys, dtype=np.int64), zeros)
