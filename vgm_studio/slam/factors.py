"""How a run's edges become factors of the pose graph: a match at its own covariance, and what
keeps the chain whole where a sequential match was left out (the odometry, or the match at the
odometry's σ where the validator was only unsure of it)."""

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
    """The factor of a matched edge: its estimate, with the matcher's covariance floored."""
    return GraphEdge(
        edge.a,
        edge.b,
        edge.estimate,
        edge_covariance(edge.match.covariance, config),
        known_inlier=edge.kind == "sequential",
    )


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
    - The match, at that narrow σ, where the validator was unsure of it
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
        return dataclasses.replace(step, measurement=edge.estimate)
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


def narrow_odometry(graph: GraphConfig, front_end: FrontEndConfig) -> GraphConfig:
    """``graph`` with the odometry σ the loop search reads."""
    return dataclasses.replace(
        graph,
        odometry_sigma_xy=front_end.drift_odometry_sigma_xy,
        odometry_sigma_theta_deg=front_end.drift_odometry_sigma_theta_deg,
    )
