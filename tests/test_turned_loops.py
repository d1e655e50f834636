"""Turned loops: the stem of a T junction driven down and back up, where the two scans of a
right loop face away from each other and share little but the side walls.

The local maps (the submap around the earlier keyframe, the trail that led to the later one)
overlap where the loop is right and not where its estimate is off; a run whose validator
rejects every loop keeps the right turned ones on that overlap and no others.
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
from vgm_studio.matching.config import MatchConfig
from vgm_studio.matching.keyframes import select_keyframes
from vgm_studio.matching.matcher import MatchResult, ScanMatcher
from vgm_studio.matching.submap import Submap
from vgm_studio.simulation.simulate import SimConfig, simulate
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.frontend import FrontEnd
from vgm_studio.slam.turned import is_turned, trail_overlap


@pytest.fixture(scope="module")
def stem(tmp_path_factory) -> tuple[list, np.ndarray]:
    """The keyframes' scans and true poses of a T junction's route."""
    folder = tmp_path_factory.mktemp("t-junction")
    path: Path = simulate(SimConfig(preset="t-junction", seed=3, num_beams=181), folder)
    log = open_log(path)
    truth = np.array([s.reference for s in log.scans])
    keyframes = select_keyframes(truth, 0.5, 20.0)
    return [log.scans[i] for i in keyframes], truth[keyframes]


def _down_and_up(truth: np.ndarray, y: float) -> tuple[int, int]:
    """The keyframes nearest (0, y) on the way down the stem and on the way back up."""
    heading = truth[:, 2]
    down = np.flatnonzero(np.sin(heading) < -0.9)
    up = np.flatnonzero(np.sin(heading) > 0.9)
    a = down[np.argmin(np.abs(truth[down, 1] - y) + np.abs(truth[down, 0]))]
    b = up[np.argmin(np.abs(truth[up, 1] - y) + np.abs(truth[up, 0]))]
    return int(a), int(b)


def _loop(a: int, b: int, estimate: np.ndarray) -> SlamEdge:
    match = MatchResult(estimate, 0, True, 0.0, 0.0, np.eye(3) * 1e-4, estimate)
    return SlamEdge("loop", a, b, estimate, match)


def test_local_maps_overlap_where_a_turned_loop_is_right(stem):
    scans, truth = stem
    a, b = _down_and_up(truth, -10.0)
    members = list(range(a - 5, a + 6))
    submap = Submap.from_scans([scans[k] for k in members], se2.between(truth[a], truth[members]))
    right = se2.between(truth[a], truth[b])
    assert is_turned(_loop(a, b, right), 60.0)
    assert not is_turned(_loop(a, a + 1, se2.between(truth[a], truth[a + 1])), 60.0)

    def overlap(estimate: np.ndarray) -> float:
        return trail_overlap(_loop(a, b, estimate), submap, scans, truth, 5, MatchConfig())

    assert overlap(right) > 0.8
    # Half a metre sideways in a 2 m corridor, or turned 10°: the walls no longer meet.
    assert overlap(se2.compose(right, np.array([0.0, 0.5, 0.0]))) < 0.5
    assert overlap(se2.compose(right, np.array([0.0, 0.0, math.radians(10.0)]))) < 0.5


def test_a_run_keeps_right_turned_loops_the_validator_rejected_on_their_overlap(stem):
    """Every loop rejected at p 0 (a network blind to turned pairs): the turned loops whose
    local maps overlap go in, each right, and none without the overlap rule."""
    scans, truth = stem
    drift = np.array([0.0, 0.0, math.radians(0.4)])  # the odometry turns left a little per step
    steps = se2.between(truth[:-1], truth[1:])
    odometry = np.vstack([truth[:1], np.zeros((len(steps), 3))])
    for k, step in enumerate(steps):
        odometry[k + 1] = se2.compose(odometry[k], se2.compose(step, drift))

    def network(edges: list[SlamEdge]) -> None:
        for e in edges:
            e.kept = e.validated = e.kind == "sequential"
            e.p_success = 1.0 if e.kept else 0.0

    def run(config: FrontEndConfig) -> list[SlamEdge]:
        front = FrontEnd(
            scans, odometry, ScanMatcher(), network, config, GraphConfig(), loop_bar=0.8
        )
        return [e for e in front.run(progress=False) if e.kind == "loop"]

    config = FrontEndConfig(place_candidates=0, place_candidates_drifted=0)
    loops = run(config)
    kept = [e for e in loops if e.kept]
    errors = np.array([se2.between(se2.between(truth[e.a], truth[e.b]), e.estimate) for e in kept])
    assert all(is_turned(e, 60.0) and e.overlap >= 0.7 for e in kept)
    # Across the stem and in heading every kept loop is right. Along it, where nothing but
    # the far end and the junction says where the robot is, up to a metre off, as any
    # matcher is in a featureless corridor; near the junction, right to centimetres.
    assert np.all(np.abs(errors[:, 1]) < 0.05) and np.all(np.abs(errors[:, 2]) < math.radians(1))
    assert np.all(np.abs(errors[:, 0]) < 1.0)
    assert (np.hypot(errors[:, 0], errors[:, 1]) < 0.05).sum() >= 3
    measured = [e for e in loops if not math.isnan(e.overlap)]
    assert len(measured) >= len(kept) > 0
    # The overlap decides: asked for more of it, fewer turned loops go in, each with that much
    # (the chain held along the stem, 0.76-0.98 of b's trail lies on a's submap).
    strict = [e for e in run(dataclasses.replace(config, turned_overlap=0.9)) if e.kept]
    assert 0 < len(strict) < len(kept) and all(e.overlap >= 0.9 for e in strict)
    # Judged only where the estimate knows roughly where b is: with the drift widened, turned
    # loops whose three σ exceed the reach stay the network's.
    far = run(dataclasses.replace(config, drift_sigma_xy=0.05, turned_max_reach=1.0))
    beyond = [e for e in far if is_turned(e, 60.0) and e.reach > 1.0]
    assert beyond and all(math.isnan(e.overlap) and not e.kept for e in beyond)
    assert any(not math.isnan(e.overlap) for e in far if e.reach <= 1.0)
    off = dataclasses.replace(config, turned_overlap=None)
    assert not any(e.kept for e in run(off))
