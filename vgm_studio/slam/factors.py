"""How a run's edges become factors of the pose graph: a match at its own covariance, and the
odometry that keeps the chain whole where a sequential match was left out."""

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
      odometry's step: the wheels vouch for the neighbourhood, the scans for the pose in it.
      A validator that never saw the building doubts many right steps, and the wide
      odometry in their place lets the chain drift between its loops.
    - Else the odometry, wide (``graph.odometry_sigma_*``): the validator was sure the match
      is wrong, or the match moved out of the window, and the odometry is often far off
      where a scan match disagrees with it.
    """
    narrow = narrow_odometry(graph, front_end)
    if edge.consistency == "rejected":
        return odometry_edge(edge.a, edge.b, odometry, narrow)
    if _unsure_in_window(edge, front_end):
        step = odometry_edge(edge.a, edge.b, odometry, narrow)
        return dataclasses.replace(step, measurement=edge.estimate)
    return odometry_edge(edge.a, edge.b, odometry, graph)


def _unsure_in_window(edge: SlamEdge, front_end: FrontEndConfig) -> bool:
    floor = front_end.sequential_unsure
    return (
        floor is not None
        and edge.kind == "sequential"
        and edge.match.covariance is not None
        and edge.p_success >= floor
        and edge.within(front_end.window_linear[0], math.radians(front_end.window_angular_deg[0]))
    )


def narrow_odometry(graph: GraphConfig, front_end: FrontEndConfig) -> GraphConfig:
    """``graph`` with the odometry σ the loop search reads."""
    return dataclasses.replace(
        graph,
        odometry_sigma_xy=front_end.drift_odometry_sigma_xy,
        odometry_sigma_theta_deg=front_end.drift_odometry_sigma_theta_deg,
    )
