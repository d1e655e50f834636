"""A sequential match the validator kept under the loop bar, as the consistency check reads it.

A simulated office driven round and back, with the odometry drifting; the validator is the
truth (every sequential match kept, a loop kept where it is right). One step inside the
revisit is replaced by a match 0.45 m off. Kept at p 0.3 the check reads that step as the
odometry's wide one and keeps the revisit's right loops on both sides of it; read as a sure
step (p 0.9), it splits the revisit and the loops before it go out.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from vgm_studio.core import se2
from vgm_studio.datasets import open_log
from vgm_studio.graph.config import GraphConfig
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.matcher import MatchResult, ScanMatcher
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.factors import fallback_edge, held_step, narrow_odometry, odometry_edge
from vgm_studio.slam.frontend import FrontEnd

LOOP_BAR = 0.8


@pytest.fixture(scope="module")
def office(tmp_path_factory) -> tuple[list, np.ndarray, np.ndarray]:
    """Keyframe scans, their true poses and an odometry that turns 0.4° left a step."""
    folder: Path = tmp_path_factory.mktemp("office")
    log = open_log(simulate(SimConfig(preset="office", seed=1, num_beams=181), folder))
    truth = np.array([s.reference for s in log.scans])
    keyframes = select_keyframes(truth, 0.5, 20.0)
    truth = truth[keyframes]
    drift = np.tile([0.0, 0.0, math.radians(0.4)], (len(truth) - 1, 1))
    return [log.scans[i] for i in keyframes], truth, _odometry(truth, drift)


def _odometry(truth: np.ndarray, errors: np.ndarray) -> np.ndarray:
    """The poses of an odometry whose step k (into pose k + 1) is off by ``errors[k]``."""
    odometry = truth[:1].copy()
    for step, error in zip(se2.between(truth[:-1], truth[1:]), errors, strict=True):
        odometry = np.vstack([odometry, se2.compose(odometry[-1], se2.compose(step, error))])
    return odometry


def _chain_only(**settings) -> FrontEndConfig:
    """A front end that searches no loop: the sequential chain alone."""
    return FrontEndConfig(
        place_candidates=0,
        place_candidates_drifted=0,
        loops_per_keyframe=0,
        turned_loops_per_keyframe=0,
        final_sweep=False,
        turned_overlap=None,
        **settings,
    )


def _right(edge: SlamEdge, truth: np.ndarray) -> bool:
    err = se2.between(se2.between(truth[edge.a], truth[edge.b]), edge.estimate)
    return math.hypot(err[0], err[1]) < 0.1 and abs(err[2]) < math.radians(2.0)


def _loops(office, bad: int | None = None, p_bad: float = 1.0) -> list[SlamEdge]:
    scans, truth, odometry = office

    def validate(edges: list[SlamEdge]) -> None:
        for e in edges:
            if e.kind == "loop":
                e.kept = e.validated = _right(e, truth)
                e.p_success = float(e.kept)
                continue
            e.kept = e.validated = True
            e.p_success = 1.0
            if bad is not None and (e.a, e.b) == (bad, bad + 1):
                wrong = se2.compose(se2.between(truth[e.a], truth[e.b]), np.array([0, 0.45, 0]))
                e.match = dataclasses.replace(e.match, estimate=wrong)
                e.p_success = p_bad

    config = FrontEndConfig(
        place_candidates=0,
        place_candidates_drifted=0,
        sequential_submap=0,
        sequential_slide_check=False,
        sequential_retry=False,
        turned_overlap=None,
    )
    front = FrontEnd(
        scans, odometry, ScanMatcher(), validate, config, GraphConfig(), loop_bar=LOOP_BAR
    )
    return [e for e in front.run(progress=False) if e.kind == "loop"]


@pytest.mark.long
def test_a_step_kept_under_the_loop_bar_does_not_split_a_revisit(office):
    truth = office[1]
    first = min(e.b for e in _loops(office) if e.kept)  # where the revisit begins
    bad = first + 4
    block = FrontEndConfig().block
    # The block that holds the bad step: its loops are checked together.
    start = 1 + (bad - 1) // block * block
    stop = start + block

    def before_and_after(p_bad: float) -> tuple[int, int, int]:
        kept = [e for e in _loops(office, bad, p_bad) if e.kept]
        assert all(_right(e, truth) for e in kept)
        here = [e for e in kept if start <= e.b < stop]
        return sum(e.b <= bad for e in here), sum(e.b > bad for e in here), len(kept)

    unsure = before_and_after(0.3)
    sure = before_and_after(0.9)
    assert unsure[0] >= 3 and unsure[1] >= 3  # both sides of the step close
    assert sure[0] == 0  # the sure wrong step vetoes the loops before it
    assert unsure[2] > sure[2]


def _chain(office, p_step: float, unsure: float | None) -> np.ndarray:
    """The front end's estimate when the validator rejects every sequential match at
    ``p_step`` and every loop."""
    scans, _, odometry = office

    def validate(edges: list[SlamEdge]) -> None:
        for e in edges:
            e.kept = e.validated = False
            e.p_success = p_step if e.kind == "sequential" else 0.0

    config = _chain_only(sequential_retry=False, sequential_unsure=unsure)
    front = FrontEnd(
        scans, odometry, ScanMatcher(), validate, config, GraphConfig(), loop_bar=LOOP_BAR
    )
    front.run(progress=False)
    return front.estimate.poses


def _heading_drift(poses: np.ndarray, truth: np.ndarray) -> float:
    """Degrees the last keyframe's heading is off once the first keyframes are aligned."""
    ends = se2.between(poses[0], poses[-1]), se2.between(truth[0], truth[-1])
    return math.degrees(abs(float(se2.wrap_angle(ends[0][2] - ends[1][2]))))


def test_an_unsure_step_in_its_window_joins_the_keyframes_at_the_match(office):
    _, truth, odometry = office
    drift = _heading_drift(odometry, truth)
    assert drift > 10.0  # the odometry turns 0.4° a step
    # The validator unsure of every step (p 0.1, under its cut): the chain follows the
    # matches, each in the smallest window around its odometry step.
    assert _heading_drift(_chain(office, 0.1, 0.02), truth) < 0.2 * drift
    # Sure they are wrong (p 0.01), or the rule off: the chain follows the odometry.
    assert _heading_drift(_chain(office, 0.01, 0.02), truth) > 0.8 * drift
    assert _heading_drift(_chain(office, 0.1, None), truth) > 0.8 * drift


def _rejected_step(p: float, moved: tuple[float, float, float], **fields) -> SlamEdge:
    guess = np.array([0.5, 0.0, 0.0])
    estimate = guess + np.array(moved)
    covariance = fields.pop("covariance", np.eye(3) * 1e-4)
    match = MatchResult(estimate, 3, True, 0.9, 0.01, covariance, estimate)
    return SlamEdge(
        "sequential", 0, 1, guess, match, p_success=p, kept=False, validated=False, **fields
    )


def test_a_rejected_step_joins_at_its_match_only_where_the_validator_was_unsure():
    odometry = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    graph, front = GraphConfig(), FrontEndConfig()
    wide = odometry_edge(0, 1, odometry, graph)
    narrow = odometry_edge(0, 1, odometry, narrow_odometry(graph, front))
    assert np.all(np.diag(narrow.covariance) < np.diag(wide.covariance))

    unsure = _rejected_step(0.1, (0.1, -0.05, math.radians(3.0)))
    factor = fallback_edge(unsure, odometry, graph, front)
    np.testing.assert_allclose(factor.measurement, unsure.estimate)
    np.testing.assert_allclose(factor.covariance, narrow.covariance)
    np.testing.assert_allclose(held_step(unsure, front), unsure.estimate)

    to_the_odometry = [
        _rejected_step(0.01, (0.1, 0.0, 0.0)),  # the validator is sure it is wrong
        _rejected_step(math.nan, (0.1, 0.0, 0.0)),  # no p at all
        _rejected_step(0.1, (0.35, 0.0, 0.0)),  # slid out of the 0.3 m window
        _rejected_step(0.1, (0.0, 0.0, math.radians(12.0))),  # turned out of its 10°
        _rejected_step(0.1, (0.1, 0.0, 0.0), covariance=None),  # a failed match
    ]
    for step in to_the_odometry:
        factor = fallback_edge(step, odometry, graph, front)
        np.testing.assert_allclose(factor.measurement, odometry[1])
        np.testing.assert_allclose(factor.covariance, wide.covariance)
        np.testing.assert_allclose(held_step(step, front), step.guess)
    # A wide match the validator kept says the odometry is off: the match, held loosely.
    doubted = _rejected_step(0.1, (0.1, 0.0, 0.0), wide_kept=True)
    factor = fallback_edge(doubted, odometry, graph, front)
    np.testing.assert_allclose(factor.measurement, doubted.estimate)
    np.testing.assert_allclose(factor.covariance, wide.covariance)
    # Taken out by the slide check: its odometry, narrow, as before.
    slid = _rejected_step(0.9, (0.1, 0.0, 0.0), consistency="rejected")
    factor = fallback_edge(slid, odometry, graph, front)
    np.testing.assert_allclose(factor.measurement, odometry[1])
    np.testing.assert_allclose(factor.covariance, narrow.covariance)
    # Off: every rejected step to the wide odometry.
    off = dataclasses.replace(front, sequential_unsure=None)
    factor = fallback_edge(unsure, odometry, graph, off)
    np.testing.assert_allclose(factor.covariance, wide.covariance)


def test_a_step_whose_wide_match_was_kept_is_held_loosely(office):
    """The odometry 25° off at one step: the small window holds only a wrong match (p 0.1),
    the wide retry finds the right one (p 0.5, kept, but under the loop bar and outside the
    window, so not believed). The wrong match must not go in at the odometry's narrow σ,
    which would let the graph veto the loops that mend it."""
    scans, truth, _ = office
    bad = 40
    kick = np.zeros((len(truth) - 1, 3))
    kick[bad - 1, 2] = math.radians(25.0)
    odometry = _odometry(truth, kick)

    def validate(edges: list[SlamEdge]) -> None:
        for e in edges:
            right = e.kind == "sequential" and _right(e, truth)
            e.kept = e.validated = right
            e.p_success = 0.5 if right else (0.1 if e.kind == "sequential" else 0.0)

    config = _chain_only()
    front = FrontEnd(
        scans[:60], odometry[:60], ScanMatcher(), validate, config, GraphConfig(), loop_bar=LOOP_BAR
    )
    step = next(e for e in front.run(progress=False) if e.kind == "sequential" and e.b == bad)
    assert not step.kept and step.wide_kept and step.at_match
    assert not _right(step, truth) and step.within(0.3, math.radians(10.0))
    factor = fallback_edge(step, odometry[:60], GraphConfig(), config)
    wide = odometry_edge(bad - 1, bad, odometry[:60], GraphConfig())
    np.testing.assert_allclose(factor.covariance, wide.covariance)
