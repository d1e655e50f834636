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
    """The odometry that joins the keyframes of a sequential edge left out of the graph.

    Wide (``graph.odometry_sigma_*``) where the validator rejected the match: there the
    odometry disagreed with a scan match, and is often far off. Narrow
    (``front_end.drift_odometry_sigma_*``) where the slide check took a kept match out: a
    match across two steps confirmed the odometry there, and a wide step would leave the graph
    unsure for nothing.
    """
    if edge.consistency == "rejected":
        graph = narrow_odometry(graph, front_end)
    return odometry_edge(edge.a, edge.b, odometry, graph)


def narrow_odometry(graph: GraphConfig, front_end: FrontEndConfig) -> GraphConfig:
    """``graph`` with the odometry σ the loop search reads."""
    return dataclasses.replace(
        graph,
        odometry_sigma_xy=front_end.drift_odometry_sigma_xy,
        odometry_sigma_theta_deg=front_end.drift_odometry_sigma_theta_deg,
    )
