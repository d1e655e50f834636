"""Sequential edges and odometry that survive a lost motion estimate.

A simulated office whose odometry jumps by a metre and tens of degrees on some steps (far
outside the smallest loop window): the sequential matcher must still find every step, which
it does only by searching again over the wide window. A wheel-less log with scans a metre
apart must give kiss-icp odometry that follows the robot, which it does only when a lost
step is searched again by the correlative matcher.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.datasets.scans import Scan
from vgm_studio.graph.config import GraphConfig
from vgm_studio.matching.correlative import CorrelativeConfig, LoopMatcher
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.matcher import MatchResult, ScanMatcher
from vgm_studio.simulation.raycast import beam_angles, cast
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam.config import FrontEndConfig, ValidationConfig
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.frontend import FrontEnd
from vgm_studio.slam.odometry import Judge, Recovery, scan_odometry
from vgm_studio.slam.sequential import SequentialMatcher
from vgm_studio.slam.validation import EdgeValidator

# Every JUMP-th step of the odometry is off by this (x, y metres, θ radians).
JUMP = 7
OFFSET = np.array([1.4, -1.0, math.radians(50.0)])


@pytest.fixture(scope="module")
def office(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("office")
    return simulate(SimConfig(preset="office", seed=4, num_beams=181, laps=0.4), folder)


def _first_keyframes(path: Path, count: int):
    """The first ``count`` keyframes' scans of a simulated log and their true poses."""
    log = open_log(path)
    truth = np.array([s.reference for s in log.scans])
    keyframes = select_keyframes(truth, 0.5, 20.0)[:count]
    return [log.scans[i] for i in keyframes], truth[keyframes]


def _sequential(scans, truth, odometry, config):
    """(metres, radians) off the true step, and kept, of every sequential edge."""
    front = FrontEnd(
        scans,
        odometry,
        ScanMatcher(),
        EdgeValidator(ValidationConfig(validator="reference"), scans, truth),
        config,
        GraphConfig(),
    )
    edges = [e for e in front.run(progress=False) if e.kind == "sequential"]
    out = []
    for e in edges:
        err = se2.between(se2.between(truth[e.a], truth[e.b]), e.estimate)
        out.append((math.hypot(err[0], err[1]), abs(err[2])))
    return np.array(out), np.array([e.kept for e in edges])


def test_sequential_edges_are_found_where_the_odometry_jumps(office):
    scans, truth = _first_keyframes(office, 60)
    steps = se2.between(truth[:-1], truth[1:])
    jumped = np.arange(len(steps)) % JUMP == JUMP - 1
    steps[jumped] = se2.compose(steps[jumped], OFFSET)
    odometry = np.vstack([truth[:1], np.zeros((len(steps), 3))])
    for k, step in enumerate(steps):
        odometry[k + 1] = se2.compose(odometry[k], step)

    config = FrontEndConfig(loop_min_gap=1000)
    errors, kept = _sequential(scans, truth, odometry, config)
    wrong = (errors[:, 0] > 0.05) | (errors[:, 1] > math.radians(1.0))
    assert jumped.sum() >= 8
    assert kept.all() and not wrong.any(), np.flatnonzero(wrong | ~kept)

    # Without the second search the validator rejects the jumped steps: the graph gets the
    # odometry's wrong step there.
    never = dataclasses.replace(config, sequential_retry=False)
    errors, kept = _sequential(scans, truth, odometry, never)
    assert kept[~jumped].all() and (~kept[jumped]).mean() > 0.5


def test_a_keyframe_whose_odometry_alone_is_off_is_matched_on_both_sides(office):
    """One keyframe in nine is placed 40° and 0.8 m off by its odometry (a scan stamped mid
    turn): both steps it joins are off, in opposite directions. The step after it must be
    searched against a submap that places that keyframe by its new match, not by the wrong
    first one, and both wide matches must go in together."""
    scans, truth = _first_keyframes(office, 60)
    odometry = truth.copy()
    glitched = np.arange(len(truth)) % 9 == 4
    odometry[glitched] = se2.compose(truth[glitched], np.array([0.8, 0.0, math.radians(40.0)]))

    errors, kept = _sequential(scans, truth, odometry, FrontEndConfig(loop_min_gap=1000))
    wrong = (errors[:, 0] > 0.05) | (errors[:, 1] > math.radians(1.0))
    assert glitched.sum() >= 6
    assert kept.all() and not wrong.any(), np.flatnonzero(wrong | ~kept)


def test_a_match_that_slid_out_of_its_window_goes_out_where_the_odometry_explains_it(office):
    """A kept match 0.6 m along from a right odometry step is taken out, and a right match
    0.6 m from a wrong odometry step stays: a match across two steps says which."""
    scans, truth = _first_keyframes(office, 30)
    config = FrontEndConfig()
    matcher = SequentialMatcher(
        scans, truth, ScanMatcher(), LoopMatcher(CorrelativeConfig(min_score=0.3)), config
    )
    along = np.array([0.6, 0.0, 0.0])

    def block_with(i: int, slid: bool) -> list[SlamEdge]:
        edges = matcher.match(range(1, 20), truth)
        e = edges[i]
        step = se2.between(truth[e.a], truth[e.b])
        if slid:  # the match walked off; the odometry is right
            e.match = dataclasses.replace(e.match, estimate=se2.compose(step, along))
        else:  # the odometry slipped; the match is right
            e.guess = se2.compose(step, along)
        return edges

    edges = block_with(8, slid=True)
    matcher.check_slides(edges)
    assert [e.kept for e in edges] == [i != 8 for i in range(len(edges))]
    assert edges[8].consistency == "rejected" and edges[8].validated

    edges = block_with(8, slid=False)
    matcher.check_slides(edges)
    assert all(e.kept for e in edges)


def test_a_slid_match_between_two_rejected_steps_is_checked_against_their_odometry(office):
    """Both neighbours of a slid match rejected by the validator (the graph joins them by
    their odometry): the match across two steps takes the neighbour's odometry step, and
    still tells a slid match (out) from a wrong odometry step (the match stays)."""
    scans, truth = _first_keyframes(office, 30)
    matcher = SequentialMatcher(
        scans, truth, ScanMatcher(), LoopMatcher(CorrelativeConfig(min_score=0.3)), FrontEndConfig()
    )
    along = np.array([0.0, 0.6, 0.0])
    for slid in (True, False):
        edges = matcher.match(range(1, 20), truth)
        for n in (7, 9):
            edges[n].kept = False
        e = edges[8]
        step = se2.between(truth[e.a], truth[e.b])
        if slid:
            e.match = dataclasses.replace(e.match, estimate=se2.compose(step, along))
        else:
            e.guess = se2.compose(step, along)
        matcher.check_slides(edges)
        assert edges[8].kept != slid
        assert edges[8].consistency == ("rejected" if slid else "not-checked")
        assert sum(x.kept for x in edges) == len(edges) - 2 - slid


class _SearchFails(LoopMatcher):
    """A loop matcher whose submap search scores nothing (a scan that sees little); its
    ``search`` still scores poses."""

    def match(self, submap, target, scan, guess, window, min_score=None):  # type: ignore[no-untyped-def]
        return MatchResult(guess, 0, False, 0.0, float("inf"), None, guess)


class _Answers(ScanMatcher):
    """A pairwise matcher that answers the step onto keyframe k (``scans[k]``) with
    ``answers[k]``."""

    def __init__(self, answers: dict[int, np.ndarray], scans: Sequence[Scan]) -> None:
        super().__init__()
        self.answers = answers
        self.index = {id(s): k for k, s in enumerate(scans)}

    def match(self, a: Scan, b: Scan, guess):  # type: ignore[no-untyped-def]
        result = super().match(a, b, guess)
        return dataclasses.replace(result, estimate=self.answers[self.index[id(b)]])


def test_a_pairwise_answer_out_of_the_window_needs_the_submap_on_its_side(office):
    """Where the submap search scores nothing, the pairwise matcher's answer stands in; one
    outside the smallest window is taken only where the submap scores it clearly above the
    odometry's step: a slid answer against a right odometry is no match (the graph joins
    that step by its odometry), a right answer against a slipped odometry is taken."""
    scans, truth = _first_keyframes(office, 30)
    steps = {k: se2.between(truth[k - 1], truth[k]) for k in range(1, 20)}
    along = np.array([0.6, 0.0, 0.0])
    answers = _Answers({}, scans)

    def matched(slid: bool, gain: float | None = 0.1) -> MatchResult:
        odometry = truth.copy()
        if slid:  # the pairwise fit walked off; the odometry is right
            answers.answers = {k: se2.compose(s, along) for k, s in steps.items()}
        else:  # the odometry slipped at keyframe 9; the answers are right
            answers.answers = dict(steps)
            odometry[9:] = se2.compose(
                truth[8], se2.compose(along, se2.between(truth[8], truth[9:]))
            )
        config = FrontEndConfig(sequential_pairwise_gain=gain)
        matcher = SequentialMatcher(
            scans, odometry, answers, _SearchFails(CorrelativeConfig(min_score=0.3)), config
        )
        return matcher.match(range(1, 20), truth)[8].match

    assert matched(slid=True).covariance is None
    assert matched(slid=True, gain=None).covariance is not None
    right = matched(slid=False)
    assert right.covariance is not None
    np.testing.assert_allclose(right.estimate, steps[9])


def test_a_step_with_no_match_stays_out_whatever_the_validator_says(office, monkeypatch):
    """The validator judges a step with no match at its odometry step, which is right here:
    it would keep it, but a step with no match is no measurement, and the odometry joins it."""
    scans, truth = _first_keyframes(office, 12)
    answers = _Answers(
        {
            k: se2.compose(se2.between(truth[k - 1], truth[k]), np.array([0.6, 0, 0]))
            for k in range(1, 12)
        },
        scans,
    )
    monkeypatch.setattr(LoopMatcher, "match", _SearchFails.match)
    front = FrontEnd(
        scans,
        truth,
        answers,
        EdgeValidator(ValidationConfig(validator="reference"), scans, truth),
        FrontEndConfig(loop_min_gap=1000),
        GraphConfig(),
    )
    edges = front.run(progress=False)
    assert len(edges) == 11 and all(e.kind == "sequential" for e in edges)
    assert all(e.p_success == 1.0 for e in edges)
    assert not any(e.kept or e.validated for e in edges)
    np.testing.assert_allclose(front.estimate.poses, truth, atol=1e-6)


class _CountingMatcher(LoopMatcher):
    calls = 0

    def match(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        type(self).calls += 1
        return super().match(*args, **kwargs)


def test_a_match_turned_out_of_its_window_is_not_taken_for_a_slide(office):
    """A match outside the window in heading only is one whose odometry turned wrong (a
    refinement slides along walls, not round them): it is not searched across two steps,
    which in a corridor can side with the odometry, and stays; one slid 0.6 m is searched."""
    scans, truth = _first_keyframes(office, 30)
    counting = _CountingMatcher(CorrelativeConfig(min_score=0.3))
    matcher = SequentialMatcher(scans, truth, ScanMatcher(), counting, FrontEndConfig())
    for offset, searched in (([0.0, 0.0, math.radians(14.0)], False), ([0.6, 0.0, 0.0], True)):
        edges = matcher.match(range(1, 20), truth)
        e = edges[8]
        e.guess = se2.compose(se2.between(truth[e.a], truth[e.b]), np.array(offset))
        before = _CountingMatcher.calls
        matcher.check_slides(edges)
        assert (_CountingMatcher.calls > before) == searched
        assert all(x.kept for x in edges)


def test_wheel_less_odometry_over_sparse_scans_follows_the_robot(tmp_path):
    path = simulate(
        SimConfig(preset="repetitive", seed=5, num_beams=181, scan_spacing=1.0, laps=0.5),
        tmp_path,
    )
    scans = [dataclasses.replace(s, odometry=None) for s in open_log(path).scans]
    truth = np.array([s.reference for s in scans])

    def wrong_steps(recovery: Recovery) -> float:
        odo = scan_odometry(scans, progress=False, recovery=recovery)
        err = se2.between(se2.between(truth[:-1], truth[1:]), se2.between(odo[:-1], odo[1:]))
        bad = (np.hypot(err[:, 0], err[:, 1]) > 0.1) | (np.abs(err[:, 2]) > math.radians(2.0))
        return float(bad.mean())

    assert len(scans) > 40
    assert wrong_steps(Recovery()) < 0.05
    assert wrong_steps(Recovery(gain=math.inf)) > 0.5


def test_wheel_less_odometry_follows_the_robot_along_walls_seen_grazing(tmp_path):
    """An office's corridors at a metre a scan: scored on end points alone, a step fitted
    best where the scan's dense near points fell on the last scan's, short of the truth
    (11% of the steps wrong); on the walls drawn whole, none."""
    path = simulate(
        SimConfig(preset="office", seed=4, num_beams=181, scan_spacing=1.0, laps=0.5), tmp_path
    )
    scans = [dataclasses.replace(s, odometry=None) for s in open_log(path).scans]
    truth = np.array([s.reference for s in scans])
    odo = scan_odometry(scans, progress=False)
    err = se2.between(se2.between(truth[:-1], truth[1:]), se2.between(odo[:-1], odo[1:]))
    bad = (np.hypot(err[:, 0], err[:, 1]) > 0.1) | (np.abs(err[:, 2]) > math.radians(2.0))
    assert len(scans) > 60
    assert bad.mean() < 0.05


def _hexagon_pair(step: float, turn_deg: float) -> list[Scan]:
    """Two scans in a hexagonal room (5 m to its corners): the first at (-step/2, 0) facing
    +x, the second at (step/2, 0) turned by ``turn_deg``. Turned by 60° about the room's
    centre, the room is itself, so every pose has look-alikes."""
    corners = [
        (5 * math.cos(math.radians(60 * k + 30)), 5 * math.sin(math.radians(60 * k + 30)))
        for k in range(7)
    ]
    walls = np.array([[*corners[k], *corners[k + 1]] for k in range(6)])
    amin, inc = beam_angles(181, 180.0)
    poses = [(-step / 2, 0.0, 0.0), (step / 2, 0.0, math.radians(turn_deg))]
    return [
        Scan(
            i,
            float(i),
            cast(p, p[2] + amin + inc * np.arange(181), walls, 30.0).astype(np.float32),
            amin,
            inc,
            30.0,
        )
        for i, p in enumerate(poses)
    ]


def test_a_judge_chooses_among_headings_the_score_cannot_tell_apart():
    """kiss-icp loses a step turned 85°; the searches of the sectors of headings find two
    look-alikes of the room scoring within the recovery's gain of each other. The judge (in a
    SLAM run, the validator) is asked about both, and the step taken is the one it prefers;
    without a judge, the higher score."""
    scans = _hexagon_pair(2.0, 85.0)
    offered: list[list[MatchResult]] = []

    def prefer(k: int | None) -> Judge:
        def judge(first: Scan, second: Scan, matches: Sequence[MatchResult]) -> np.ndarray:
            assert (first, second) == (scans[0], scans[1])
            offered.append(list(matches))
            return np.eye(len(matches))[k if k is not None else 0]

        return Judge(judge, bar=0.5)

    scan_odometry(scans, progress=False, judge=prefer(None))
    assert len(offered) == 1
    candidates = offered[0]
    assert len(candidates) >= 2
    scores = [m.score or 0.0 for m in candidates]
    assert (1.0 + Recovery().gain) * min(scores) >= max(scores)
    headings = sorted(float(m.estimate[2]) for m in candidates)
    assert min(np.diff(headings)) > math.radians(30.0)
    for k, m in enumerate(candidates):
        step = scan_odometry(scans, progress=False, judge=prefer(k))[1]
        assert np.allclose(step, m.estimate, atol=1e-6)
    best = candidates[int(np.argmax(scores))]
    assert np.allclose(scan_odometry(scans, progress=False)[1], best.estimate, atol=1e-6)


def test_a_judge_that_rejects_every_heading_leaves_the_step_that_turns_least():
    """Where the judge accepts none of the candidates (every p under its bar), its p only
    ranks failures: the step taken is the one that turns least, whichever it ranks first."""
    scans = _hexagon_pair(2.0, 85.0)
    offered: list[list[MatchResult]] = []

    def rank_by_turn(first: Scan, second: Scan, matches: Sequence[MatchResult]) -> np.ndarray:
        offered.append(list(matches))
        # The most-turned candidate ranks first, all of them far under the bar.
        return 0.01 + 0.01 * np.abs([m.estimate[2] for m in matches])

    step = scan_odometry(scans, progress=False, judge=Judge(rank_by_turn, bar=0.5))[1]
    candidates = offered[0]
    assert len(candidates) >= 2
    least = min(candidates, key=lambda m: abs(float(m.estimate[2])))
    most = max(candidates, key=lambda m: abs(float(m.estimate[2])))
    assert abs(float(most.estimate[2])) - abs(float(least.estimate[2])) > math.radians(5.0)
    assert np.allclose(step, least.estimate, atol=1e-6)
    # Over the bar, the same ranks choose: the most-turned candidate.
    offered.clear()
    step = scan_odometry(scans, progress=False, judge=Judge(rank_by_turn, bar=0.0))[1]
    assert np.allclose(step, most.estimate, atol=1e-6)


class _AliasingMatcher(LoopMatcher):
    """Over the wide window, puts keyframe ``alias_of`` turned by ``turn`` from its true
    step, with every point an inlier: a search that found a convincing wrong pose (fhw
    keyframes 55–56, a robot turning on the spot)."""

    def __init__(self, scans, truth, alias_of: int, turn: float) -> None:
        super().__init__(CorrelativeConfig(min_score=0.3))
        self.scans, self.truth, self.alias_of, self.turn = scans, truth, alias_of, turn

    def match(self, submap, target, scan, guess, window, min_score=None):  # type: ignore[no-untyped-def]
        found = super().match(submap, target, scan, guess, window, min_score)
        k = self.alias_of
        if scan is self.scans[k] and target is self.scans[k - 1] and window.angular > 1.0:
            step = se2.between(self.truth[k - 1], self.truth[k])
            wrong = se2.compose(step, np.array([0.0, 0.0, self.turn]))
            return dataclasses.replace(found, estimate=wrong, inlier_ratio=1.0, score=1.0)
        return found


@pytest.mark.parametrize("odometry_wrong", [False, True])
def test_a_wide_match_that_turns_a_matched_chain_needs_a_match_across_two_steps(
    office, odometry_wrong
):
    """A rejected step between two matched ones, searched again over the wide window, where
    the search finds a pose 60° off the odometry and the validator passes it: it goes in
    only where a match across two steps agrees with it rather than with the odometry. A
    wrong turn (the odometry right) stays out; a right one (the odometry 60° off) goes in."""
    scans, truth = _first_keyframes(office, 30)
    turn = math.radians(60.0)
    k = 9  # edges[8] joins keyframes 8 and 9
    odometry = truth.copy()
    if odometry_wrong:  # step 8 alone is 60° off
        odometry[k] = se2.compose(truth[k], np.array([0.0, 0.0, -turn]))
        odometry[k + 1 :] = se2.compose(odometry[k], se2.between(truth[k], truth[k + 1 :]))
    aliasing = _AliasingMatcher(scans, truth, k, 0.0 if odometry_wrong else turn)
    matcher = SequentialMatcher(scans, odometry, ScanMatcher(), aliasing, FrontEndConfig())
    edges = matcher.match(range(1, 20), truth)
    # The validator rejected the first match, which put little of the scan on the submap.
    edges[8].kept = False
    edges[8].match = dataclasses.replace(edges[8].match, inlier_ratio=0.5)

    def keep_all(batch: list[SlamEdge]) -> None:
        for e in batch:
            e.kept = True

    matcher.retry(edges, keep_all)
    step = se2.between(truth[8], truth[9])
    replaced = edges[8].kept
    assert replaced == odometry_wrong
    if replaced:
        err = se2.between(step, edges[8].estimate)
        assert abs(err[2]) < math.radians(1.0) and math.hypot(err[0], err[1]) < 0.05
    assert all(e.kept for i, e in enumerate(edges) if i != 8)


@pytest.mark.parametrize("p", [0.7, 0.9])
def test_a_wide_match_that_says_the_odometry_is_off_needs_the_loop_bar(office, p):
    """A rejected step whose odometry is 60° off, searched again over the wide window: the
    right wide match says the odometry is wrong, a surprise like a loop, so it takes the
    rejected match's place only where its p reaches the loop bar (CSAIL keyframes 52–53: a
    wrong wide match 2.6 m sideways went in at p 0.72)."""
    scans, truth = _first_keyframes(office, 30)
    turn = math.radians(60.0)
    k = 9  # edges[8] joins keyframes 8 and 9
    odometry = truth.copy()
    odometry[k] = se2.compose(truth[k], np.array([0.0, 0.0, -turn]))
    odometry[k + 1 :] = se2.compose(odometry[k], se2.between(truth[k], truth[k + 1 :]))
    aliasing = _AliasingMatcher(scans, truth, k, 0.0)
    matcher = SequentialMatcher(scans, odometry, ScanMatcher(), aliasing, FrontEndConfig())
    edges = matcher.match(range(1, 20), truth)
    edges[8].kept = False
    edges[8].match = dataclasses.replace(edges[8].match, inlier_ratio=0.5)
    first = edges[8]

    def passes_at_p(batch: list[SlamEdge]) -> None:
        for e in batch:
            e.kept, e.p_success = True, p

    matcher.retry(edges, passes_at_p, loop_bar=0.8)
    assert edges[8].kept == (p >= 0.8)
    assert (edges[8] is first) == (p < 0.8)
    if p >= 0.8:
        err = se2.between(se2.between(truth[8], truth[9]), edges[8].estimate)
        assert abs(err[2]) < math.radians(1.0)
