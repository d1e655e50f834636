"""A gtsam Pose2 factor graph over keyframes: batch optimisation (plain, Huber or GNC) and an
incremental running estimate (iSAM2) for the front end's loop search."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from vgm_studio.graph.config import GraphConfig, RobustName

# The first keyframe is the origin of the map; a tight prior fixes the gauge.
_PRIOR = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-5]))


@dataclass(frozen=True)
class GraphEdge:
    """A relative-pose factor between two keyframes.

    Attributes:
        a: Index of the first keyframe.
        b: Index of the second keyframe.
        measurement: Pose of b in the frame of a, (x, y, θ).
        covariance: 3×3 covariance of the measurement (the floor already added).
        known_inlier: GNC must not reject it (the chain that holds the graph together).
    """

    a: int
    b: int
    measurement: NDArray[np.float64]
    covariance: NDArray[np.float64]
    known_inlier: bool = False


@dataclass(frozen=True)
class OptimizeResult:
    """Optimised keyframe poses and what the robust back end made of each edge.

    Attributes:
        poses: (N, 3) keyframe poses.
        weights: Per edge, GNC's final weight (1 inlier, 0 rejected); all ones otherwise.
        iterations: Optimiser iterations.
    """

    poses: NDArray[np.float64]
    weights: NDArray[np.float64]
    iterations: int


def edge_covariance(
    covariance: NDArray[np.float64] | None, config: GraphConfig, distance: float = 0.0
) -> NDArray[np.float64]:
    """The matcher's covariance plus the configured floor; the odometry fallback without one.

    The matcher's σ̂²·(JᵀJ)⁻¹ is the spread of a few hundred point residuals: millimetres, which
    would make every edge far more certain than the scans and their timing allow.
    """
    floor = np.diag(
        [
            config.min_sigma_xy**2,
            config.min_sigma_xy**2,
            math.radians(config.min_sigma_theta_deg) ** 2,
        ]
    )
    if covariance is None or not np.all(np.isfinite(covariance)):
        sxy = config.min_sigma_xy + config.odometry_sigma_xy * distance
        sth = math.radians(config.odometry_sigma_theta_deg)
        return np.diag([sxy**2, sxy**2, sth**2])
    cov = 0.5 * (np.asarray(covariance, dtype=np.float64) + np.asarray(covariance).T)
    return cov + floor


def _noise(edge: GraphEdge, robust: RobustName, config: GraphConfig) -> gtsam.noiseModel.Base:
    gaussian = gtsam.noiseModel.Gaussian.Covariance(edge.covariance)
    if robust == "huber":
        kernel = gtsam.noiseModel.mEstimator.Huber.Create(config.huber_k)
        return gtsam.noiseModel.Robust.Create(kernel, gaussian)
    return gaussian


def _pose(p: NDArray[np.float64]) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


def _graph(
    edges: Sequence[GraphEdge],
    origin: NDArray[np.float64],
    robust: RobustName,
    config: GraphConfig,
    anchor: int = 0,
) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(anchor, _pose(origin), _PRIOR))
    for e in edges:
        graph.add(
            gtsam.BetweenFactorPose2(e.a, e.b, _pose(e.measurement), _noise(e, robust, config))
        )
    return graph


def _values(poses: NDArray[np.float64]) -> gtsam.Values:
    values = gtsam.Values()
    for i, p in enumerate(poses):
        values.insert(i, _pose(p))
    return values


def _poses(values: gtsam.Values, count: int) -> NDArray[np.float64]:
    """The (count, 3) poses of keys 0..count-1, which are all the values hold.

    gtsam's own extraction, in key order: a Python loop over ``atPose2`` took 10 ms for 4,000
    poses, once per update of the running estimate.
    """
    out = np.asarray(gtsam.utilities.extractPose2(values), dtype=np.float64)
    if out.shape != (count, 3):
        raise ValueError(f"expected the poses of keys 0..{count - 1}, got {out.shape[0]}")
    return out


def optimize(
    initial: NDArray[np.float64],
    edges: Sequence[GraphEdge],
    config: GraphConfig,
    robust: RobustName | None = None,
    anchor: int = 0,
) -> OptimizeResult:
    """Optimises the keyframe poses from ``initial`` under ``edges``.

    Args:
        initial: (N, 3) initial keyframe poses; keyframe ``anchor`` stays where it is.
        edges: The factors; every keyframe should be reachable through them.
        config: Noise floors and robust settings.
        robust: Overrides ``config.robust``.
        anchor: The keyframe that fixes the map's frame (a graph file's ``FIX``).

    Returns:
        The optimised poses and, for GNC, each edge's final weight.
    """
    robust = robust or config.robust
    count = len(initial)
    # GNC wants plain Gaussian factors: it weights them itself.
    graph = _graph(edges, initial[anchor], "none" if robust == "gnc" else robust, config, anchor)
    values = _values(initial)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(100)
    weights = np.ones(len(edges))
    if robust == "gnc":
        params = gtsam.GncLMParams(lm)
        params.setLossType(gtsam.GncLossType.TLS)
        # Factor 0 is the prior; the chain of sequential edges keeps the graph connected.
        params.setKnownInliers([0] + [k + 1 for k, e in enumerate(edges) if e.known_inlier])
        gnc = gtsam.GncLMOptimizer(graph, values, params)
        gnc.setInlierCostThresholdsAtProbability(config.gnc_probability)
        result = gnc.optimize()
        weights = np.asarray(gnc.getWeights(), dtype=np.float64)[1:]
        return OptimizeResult(_poses(result, count), weights, 0)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    result = optimizer.optimize()
    return OptimizeResult(_poses(result, count), weights, int(optimizer.iterations()))


class RunningEstimate:
    """The graph as the front end builds it, kept optimised incrementally with iSAM2.

    Loop candidates are searched in this estimate, so closing one loop corrects where the
    next ones are looked for.

    Attributes:
        restarts: 1 once iSAM2 has been rebuilt with QR factorisation (see ``update``), else 0.
    """

    def __init__(self, origin: NDArray[np.float64], config: GraphConfig) -> None:
        self._config = config
        # GNC has no incremental form; Huber stands in for it while the front end runs.
        self._robust: RobustName = "none" if config.robust == "none" else "huber"
        self._isam = gtsam.ISAM2(gtsam.ISAM2Params())
        # Every factor given so far, to rebuild iSAM2 from when gtsam gives up (see ``update``);
        # kept here rather than read back from iSAM2, whose own list after a throw is gtsam's
        # internal state (whole in 4.3, but nothing promises it).
        self._factors = gtsam.NonlinearFactorGraph()
        self._pending_graph = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._pending_graph.add(gtsam.PriorFactorPose2(0, _pose(origin), _PRIOR))
        self._pending_values.insert(0, _pose(origin))
        self._count = 1
        self._poses = np.asarray(origin, dtype=np.float64).reshape(1, 3)
        self.restarts = 0

    def __len__(self) -> int:
        return self._count

    def add_keyframe(self, guess: NDArray[np.float64]) -> int:
        """Adds the next keyframe at ``guess`` (applied at ``update``); returns its index."""
        index = self._count
        self._pending_values.insert(index, _pose(guess))
        self._poses = np.vstack([self._poses, np.asarray(guess, dtype=np.float64)])
        self._count += 1
        return index

    def add_edge(self, edge: GraphEdge) -> None:
        noise = _noise(edge, self._robust, self._config)
        self._pending_graph.add(
            gtsam.BetweenFactorPose2(edge.a, edge.b, _pose(edge.measurement), noise)
        )

    def update(self, extra_iterations: int = 0) -> NDArray[np.float64]:
        """Folds the pending keyframes and edges in; returns the (N, 3) current estimate.

        gtsam's Cholesky calls a pivot indeterminate when it is under 2⁻²⁴ of the variable's
        own information. iSAM2 eliminates the keyframes just touched (the newest, those a new
        loop joins) last, so their pivots are near their marginal information: after a long
        run of weak odometry (marginal σ of tens of metres against centimetres per edge) that
        trips the check although the system is sound. The solver is then rebuilt on every
        factor with QR, which has no such check, and stays so.
        """
        self._factors.push_back(self._pending_graph)
        try:
            estimate = self._solve(self._pending_graph, self._pending_values, extra_iterations)
        except RuntimeError as exc:
            if "Indeterminate" not in str(exc) or self.restarts:
                raise
            params = gtsam.ISAM2Params()
            params.setFactorization("QR")
            self._isam = gtsam.ISAM2(params)
            self.restarts += 1
            estimate = self._solve(self._factors, _values(self._poses), extra_iterations)
        self._pending_graph = gtsam.NonlinearFactorGraph()
        self._pending_values = gtsam.Values()
        self._poses = _poses(estimate, self._count)
        return self._poses

    def _solve(
        self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, extra_iterations: int
    ) -> gtsam.Values:
        self._isam.update(factors, values)
        # A loop closure moves many poses at once; a few more relinearisations settle it.
        for _ in range(extra_iterations):
            self._isam.update()
        return self._isam.calculateEstimate()

    @property
    def poses(self) -> NDArray[np.float64]:
        """The (N, 3) estimate as of the last ``update``, with guesses for keyframes since."""
        return self._poses
