"""A kept sequential match and its odometry step fused by their information: the odometry
holds the step where the match's score could slide, the match holds it where it is pinned."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vgm_studio.graph.config import GraphConfig
from vgm_studio.matching.matcher import MatchResult
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import SlamEdge
from vgm_studio.slam.factors import fallback_edge, narrow_odometry, odometry_edge, sequential_edge

ODOMETRY = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])


def _step(
    moved: tuple[float, float, float],
    spread: tuple[float, float, float] | None,
    guess_share: float = 0.9,
) -> SlamEdge:
    """A kept step matched ``moved`` away from the odometry's, its score spread by σ
    ``spread`` (x, y, θ) around the match, the odometry's step keeping ``guess_share`` of
    the match's score."""
    estimate = ODOMETRY[1] + np.array(moved)
    cov = np.diag([1e-6, 1e-6, 1e-8])
    surface = None if spread is None else np.diag(np.square(spread))
    match = MatchResult(
        estimate, 3, True, 0.9, 0.01, cov, estimate, spread=surface, guess_share=guess_share
    )
    return SlamEdge("sequential", 0, 1, ODOMETRY[1].copy(), match, p_success=0.95)


def test_a_match_that_could_slide_along_the_corridor_follows_the_odometry_there():
    slid = _step((-0.45, 0.03, math.radians(0.5)), spread=(0.2, 0.005, 0.001))
    factor = sequential_edge(slid, ODOMETRY, GraphConfig(), FrontEndConfig())
    # Along x the odometry (σ 7 cm over the metre) outweighs a match that could be anywhere
    # in 0.2 m; across and in heading the pinned match stands.
    assert abs(factor.measurement[0] - 1.0) < 0.1
    assert abs(factor.measurement[1] - 0.03) < 0.01
    assert abs(factor.measurement[2] - math.radians(0.5)) < math.radians(0.05)
    assert factor.covariance[0, 0] < 0.07**2


def test_a_pinned_match_stands():
    pinned = _step((-0.1, 0.02, 0.0), spread=(0.005, 0.005, 0.001))
    factor = sequential_edge(pinned, ODOMETRY, GraphConfig(), FrontEndConfig())
    np.testing.assert_allclose(factor.measurement[:2], pinned.estimate[:2], atol=0.02)


def test_an_odometry_the_scans_rule_out_or_the_rule_off_leaves_the_match():
    turned = _step((-0.45, 0.0, math.radians(10.0)), spread=(0.2, 0.005, 0.001))
    factor = sequential_edge(turned, ODOMETRY, GraphConfig(), FrontEndConfig())
    np.testing.assert_allclose(factor.measurement, turned.estimate)
    # The scans at the odometry's step keep half the match's score: they rule it out.
    unsupported = _step((-0.45, 0.0, 0.0), spread=(0.2, 0.005, 0.001), guess_share=0.5)
    factor = sequential_edge(unsupported, ODOMETRY, GraphConfig(), FrontEndConfig())
    np.testing.assert_allclose(factor.measurement, unsupported.estimate)
    off = dataclasses.replace(FrontEndConfig(), sequential_odometry=False)
    slid = _step((-0.45, 0.0, 0.0), spread=(0.2, 0.005, 0.001))
    np.testing.assert_allclose(
        sequential_edge(slid, ODOMETRY, GraphConfig(), off).measurement, slid.estimate
    )


def test_a_step_held_at_its_match_is_weighed_with_the_odometry_too():
    """The validator unsure (p 0.1) of a match that could slide 0.2 m along x: the step the
    graph holds lies near the odometry along x, at the odometry's narrow σ."""
    unsure = dataclasses.replace(
        _step((-0.2, 0.03, 0.0), spread=(0.2, 0.005, 0.001)),
        p_success=0.1,
        kept=False,
        validated=False,
    )
    graph, front = GraphConfig(), FrontEndConfig()
    factor = fallback_edge(unsure, ODOMETRY, graph, front)
    narrow = odometry_edge(0, 1, ODOMETRY, narrow_odometry(graph, front))
    assert abs(factor.measurement[0] - 1.0) < 0.05
    assert abs(factor.measurement[1] - 0.03) < 0.01
    np.testing.assert_allclose(factor.covariance, narrow.covariance)
