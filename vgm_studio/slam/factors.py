"""How a run's edges become factors of the pose graph: a match at its own covariance, and what
keeps the chain whole where a sequential match was left out (the odometry, or the match at the
odometry's σ where the validator was only unsure of it); and the narrower factors through which
the loop search reads the chain's drift."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from vgm_studio.core import se2
from vgm_studio.graph.config import GraphConfig
from vgm_studio.graph.pose_graph import GraphEdge, edge_covariance
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import SlamEdge


def graph_edge(edge: SlamEdge, config: GraphConfig) -> GraphEdge:
    """The factor of a matched edge: its estimate, with the matcher's covariance, in b's
    frame as the factor reads it (``matcher_covariance``), floored."""
    return GraphEdge(
        edge.a,
        edge.b,
        edge.estimate,
        edge_covariance(matcher_covariance(edge), config),
        known_inlier=edge.kind == "sequential",
    )


def kept_edge(
    edge: SlamEdge, odometry: NDArray[np.float64], graph: GraphConfig, front_end: FrontEndConfig
) -> GraphEdge:
    """The factor of an edge that goes into the graph: a sequential step weighed with its
    odometry (``sequential_edge``), a loop at its matcher's covariance (``graph_edge``)."""
    if edge.kind == "sequential":
        return sequential_edge(edge, odometry, graph, front_end)
    return graph_edge(edge, graph)


def sequential_edge(
    edge: SlamEdge, odometry: NDArray[np.float64], graph: GraphConfig, front_end: FrontEndConfig
) -> GraphEdge:
    """The factor of a kept sequential match: the match and its odometry step fused, each by
    its information, where ``front_end.sequential_odometry`` asks for it; else the match alone.

    The match weighs by its covariance and the spread of its score's surface
    (``matcher_covariance``), the odometry by its translation at
    ``front_end.drift_odometry_sigma_xy``: along a corridor, where the match could slide, the
    odometry holds the step; where the match is pinned, the match does. Not where the
    headings differ by more than three ``front_end.drift_odometry_sigma_theta_deg``, nor
    where the scans at the odometry's step keep under ``front_end.sequential_odometry_share``
    of the match's score: then the odometry is off, and the match stands alone.
    """
    match = graph_edge(edge, graph)
    if not front_end.sequential_odometry:
        return match
    step = odometry_edge(edge.a, edge.b, odometry, narrow_odometry(graph, front_end))
    # The odometry's step seen from the match, in the match's own frame, as its factor reads
    # errors; steps differ by centimetres and degrees, so the tangent is this difference.
    gap = se2.between(match.measurement, step.measurement)
    if abs(gap[2]) > 3.0 * math.radians(front_end.drift_odometry_sigma_theta_deg):
        return match  # the odometry turned otherwise: its translation is in doubt too
    share = edge.match.guess_share
    if share is None or share < front_end.sequential_odometry_share:
        return match  # the scans rule the odometry's step out
    info_match = np.linalg.inv(match.covariance)
    # The odometry's translation only: a heading bias of a few tenths of a degree a step, a
    # share of it taken at every step, would bend the chain.
    info_step = np.zeros((3, 3))
    info_step[:2, :2] = np.linalg.inv(step.covariance[:2, :2])
    cov = np.linalg.inv(info_match + info_step)
    shift = cov @ info_step @ gap
    fused = se2.compose(match.measurement, shift)
    return GraphEdge(edge.a, edge.b, fused, 0.5 * (cov + cov.T), known_inlier=True)


def matcher_covariance(edge: SlamEdge, spread: bool = True) -> NDArray[np.float64] | None:
    """The matcher's covariance of a matched edge in b's own frame, where a factor measures
    its error; None where the matcher gave none. The matcher gives it in a's frame, the one
    it searched in. With ``spread``, the spread of its score's surface is added."""
    cov = edge.match.covariance
    if cov is None or not np.all(np.isfinite(cov)):
        return None
    if spread and edge.match.spread is not None:
        cov = np.asarray(cov) + edge.match.spread
    return se2.covariance_in_own_frame(cov, float(edge.estimate[2]))


def odometry_edge(a: int, b: int, odometry: NDArray[np.float64], config: GraphConfig) -> GraphEdge:
    """The odometry fallback that keeps the chain whole where a sequential edge was rejected."""
    delta = se2.between(odometry[a], odometry[b])
    cov = edge_covariance(None, config, distance=float(math.hypot(delta[0], delta[1])))
    return GraphEdge(a, b, delta, cov, known_inlier=True)


def fallback_edge(
    edge: SlamEdge, odometry: NDArray[np.float64], graph: GraphConfig, front_end: FrontEndConfig
) -> GraphEdge:
    """What joins the keyframes of a sequential edge whose match was left out of the graph.

    - The odometry, narrow (``front_end.drift_odometry_sigma_*``), where the slide check took
      a kept match out: a match across two steps confirmed the odometry there, and a wide
      step would leave the graph unsure for nothing.
    - The match (weighed with the odometry's step as a kept one is, ``sequential_edge``),
      at that narrow σ, where the validator was unsure of it
      (``front_end.sequential_unsure``) and it lies in the smallest window around the
      odometry's step (``joined_at_match``): the wheels vouch for the neighbourhood, the
      scans for the pose in it. A validator that never saw the building doubts many right
      steps, and the wide odometry in their place lets the chain drift between its loops.
      At the wide σ instead where a match over the wide window that the validator kept says
      the odometry is off (``SlamEdge.wide_kept``): then the odometry and the match near it
      are both in doubt, and the graph holds neither firmly (the small window's match
      centres it: on freiburg-campus held out, keyframe 194's match was 0.8° off where the
      odometry was 4.1° off).
    - Else the odometry, wide (``graph.odometry_sigma_*``): the validator was sure the match
      is wrong, or the match moved out of the window, and the odometry is often far off
      where a scan match disagrees with it.
    """
    narrow = narrow_odometry(graph, front_end)
    if edge.consistency == "rejected":
        return odometry_edge(edge.a, edge.b, odometry, narrow)
    if joined_at_match(edge, front_end):
        step = odometry_edge(edge.a, edge.b, odometry, graph if edge.wide_kept else narrow)
        fused = sequential_edge(edge, odometry, graph, front_end).measurement
        return dataclasses.replace(step, measurement=fused)
    return odometry_edge(edge.a, edge.b, odometry, graph)


def joined_at_match(edge: SlamEdge, front_end: FrontEndConfig) -> bool:
    """Whether a rejected sequential step joins its keyframes at its match (``fallback_edge``):
    the validator unsure of it and the match in the smallest window around the odometry's
    step."""
    floor = front_end.sequential_unsure
    return (
        floor is not None
        and edge.kind == "sequential"
        and not edge.kept
        and edge.consistency != "rejected"
        and edge.match.covariance is not None
        and edge.p_success >= floor
        and edge.within(front_end.window_linear[0], math.radians(front_end.window_angular_deg[0]))
    )


def held_step(edge: SlamEdge, front_end: FrontEndConfig) -> NDArray[np.float64]:
    """A sequential step as the graph will hold it: the match where it went in or joins the
    keyframes at its match, else the odometry's step."""
    return edge.estimate if edge.kept or joined_at_match(edge, front_end) else edge.guess


def drift_edge(edge: SlamEdge, graph: GraphConfig, front_end: FrontEndConfig) -> GraphEdge:
    """A kept sequential edge as the loop search sees it: the matcher's covariance plus a
    scan matcher's drift (``front_end.drift_sigma_*``), not the graph's wider floors."""
    base = matcher_covariance(edge, spread=False)
    if base is None:
        return graph_edge(edge, graph)
    floor = [front_end.drift_sigma_xy**2] * 2 + [math.radians(front_end.drift_sigma_theta_deg) ** 2]
    return GraphEdge(edge.a, edge.b, edge.estimate, base + np.diag(floor), True)


def drift_odometry_edge(
    edge: SlamEdge, odometry: NDArray[np.float64], graph: GraphConfig, front_end: FrontEndConfig
) -> GraphEdge:
    """A rejected sequential step's odometry as the loop search sees it: narrower than the
    graph's (wide) fallback. Windows widened over every doubted step would hold aliases, and
    so would a surprise test that any doubted step explains (CSAIL: one alias 14 m off passed
    alone); where the odometry was truly lost, place recognition finds the revisit, and the
    graph's wide fallback lets those loops pull it straight."""
    return odometry_edge(edge.a, edge.b, odometry, narrow_odometry(graph, front_end))


def narrow_odometry(graph: GraphConfig, front_end: FrontEndConfig) -> GraphConfig:
    """``graph`` with the odometry σ the loop search reads."""
    return dataclasses.replace(
        graph,
        odometry_sigma_xy=front_end.drift_odometry_sigma_xy,
        odometry_sigma_theta_deg=front_end.drift_odometry_sigma_theta_deg,
    )


def checked_as(
    edge: SlamEdge,
    factor: GraphEdge,
    odometry: NDArray[np.float64],
    graph: GraphConfig,
    loop_bar: float | None,
    inside: bool,
) -> GraphEdge:
    """A sequential edge as the consistency check reads the chain: a match that lies
    outside the smallest window around its odometry step and that the validator kept
    under the loop bar reads as the odometry's wide step, centred on the match.

    There the match and the odometry disagree and the validator is not sure of the
    match: the step is kept (likelier right than the odometry), but a check that held it
    at the matcher's centimetres would call a revisit wrong for disagreeing with it. On
    CSAIL a model that kept keyframes 322→323 at p 0.21 (0.45 m off; the odometry 14°
    off) lost the revisit's right loops 114→321 and 116→323 so, and its map ended 0.43 m
    off; read so, 0.11 m (the bundled model, which had rejected that step: 0.085 →
    0.070 m). Every unsure step read so, agreeing with its odometry or not, let the
    infinite corridor's aliases in: 0.057 → 4.9 m.

    ``inside``: the match lies in that smallest window (``SequentialMatcher.inside``).
    """
    if not edge.kept or loop_bar is None or not edge.p_success < loop_bar or inside:
        return factor
    wide = odometry_edge(edge.a, edge.b, odometry, graph)
    return dataclasses.replace(factor, covariance=wide.covariance)
