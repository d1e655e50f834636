"""The front end: sequential edges between keyframes and loop candidates searched in the
current graph estimate, each matched, validated and handed to the running estimate.

Keyframes are taken a block at a time. For each block the sequential edges are matched from
odometry and validated together (the validator is fastest on batches), the running estimate
is updated, then every keyframe of the block looks for earlier keyframes near it in that
estimate (a KD-tree over their positions), and those pairs are matched from the estimate's
relative pose, validated, and the kept ones closed into the graph before the next block.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from tqdm import tqdm

from vgm_studio.core import se2
from vgm_studio.datasets.scans import Scan
from vgm_studio.graph.config import GraphConfig
from vgm_studio.graph.pose_graph import GraphEdge, RunningEstimate, edge_covariance
from vgm_studio.matching.matcher import ScanMatcher
from vgm_studio.slam.config import FrontEndConfig
from vgm_studio.slam.edges import SlamEdge, SlamEdgeKind

Validate = Callable[[Sequence[SlamEdge]], None]


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


def false_loop_pairs(odometry: NDArray[np.float64], config: FrontEndConfig) -> dict[int, list[int]]:
    """Keyframe pairs for injected false loops, keyed by the later keyframe.

    Each pair is at least ``loop_min_gap`` keyframes and ``false_loop_distance`` metres
    apart in odometry, so a guess that puts them at one place is wrong by construction.
    """
    rng = np.random.default_rng([config.seed, 2])
    out: dict[int, list[int]] = {}
    count = len(odometry)
    for _ in range(100 * config.false_loops):
        if sum(map(len, out.values())) >= config.false_loops or count <= config.loop_min_gap:
            break
        b = int(rng.integers(config.loop_min_gap, count))
        a = int(rng.integers(0, b - config.loop_min_gap + 1))
        far = math.dist(odometry[a, :2], odometry[b, :2]) >= config.false_loop_distance
        if far and a not in out.get(b, []):
            out.setdefault(b, []).append(a)
    return out


class FrontEnd:
    """Builds the edges of a run over its keyframes.

    Args:
        scans: The keyframes' scans.
        odometry: (K, 3) odometry poses of the keyframes.
        matcher: The scan matcher.
        validate: Sets ``p_success`` and ``kept`` on a block of edges.
        config: Keyframe, loop-search and injection settings.
        graph: Noise floors and robust settings for the running estimate.
    """

    def __init__(
        self,
        scans: Sequence[Scan],
        odometry: NDArray[np.float64],
        matcher: ScanMatcher,
        validate: Validate,
        config: FrontEndConfig,
        graph: GraphConfig,
    ) -> None:
        self.scans = scans
        self.odometry = odometry
        self.matcher = matcher
        self.validate = validate
        self.config = config
        self.graph = graph
        self.estimate = RunningEstimate(odometry[0], graph)
        self.edges: list[SlamEdge] = []
        self._false = false_loop_pairs(odometry, config) if config.false_loops else {}
        self._noise = np.random.default_rng([config.seed, 3])

    def run(self, progress: bool = True) -> list[SlamEdge]:
        """Matches and validates every edge; ``self.estimate`` ends with the kept ones."""
        count = len(self.scans)
        bar = tqdm(
            total=count, desc="front end", unit="keyframe", disable=None if progress else True
        )
        bar.update(1)
        for start in range(1, count, self.config.block):
            block = range(start, min(start + self.config.block, count))
            self._sequential(block)
            self._loops(block)
            bar.update(len(block))
            bar.set_postfix(
                loops=sum(e.kind == "loop" for e in self.edges),
                kept=sum(e.kind == "loop" and e.kept for e in self.edges),
            )
        bar.close()
        return self.edges

    def _match(
        self,
        kind: SlamEdgeKind,
        a: int,
        b: int,
        guess: NDArray[np.float64],
        injected: bool = False,
    ) -> SlamEdge:
        result = self.matcher.match(self.scans[a], self.scans[b], guess)
        return SlamEdge(kind, a, b, guess, result, injected)

    def _sequential(self, block: range) -> None:
        odo = self.odometry
        edges = [
            self._match("sequential", k - 1, k, se2.between(odo[k - 1], odo[k])) for k in block
        ]
        self.validate(edges)
        for e in edges:
            factor = (
                graph_edge(e, self.graph) if e.kept else odometry_edge(e.a, e.b, odo, self.graph)
            )
            self.estimate.add_keyframe(se2.compose(self.estimate.poses[e.a], factor.measurement))
            self.estimate.add_edge(factor)
        self.edges.extend(edges)
        self.estimate.update()

    def _loops(self, block: range) -> None:
        cfg = self.config
        poses = self.estimate.poses
        newest_old = block.stop - 1 - cfg.loop_min_gap
        pairs: list[tuple[int, int, bool]] = []
        if newest_old >= 0:
            tree = cKDTree(poses[: newest_old + 1, :2])
            max_angle = math.radians(cfg.loop_max_angle_deg)
            for b in block:
                near = tree.query_ball_point(poses[b, :2], cfg.loop_radius)
                near = [a for a in near if b - a >= cfg.loop_min_gap]
                near = [
                    a for a in near if abs(se2.wrap_angle(poses[b, 2] - poses[a, 2])) <= max_angle
                ]
                near.sort(key=lambda a: math.dist(poses[a, :2], poses[b, :2]))
                pairs += [(a, b, False) for a in near[: cfg.loops_per_keyframe]]
        for b in block:
            pairs += [(a, b, True) for a in self._false.get(b, [])]
        edges = []
        for a, b, injected in pairs:
            guess = se2.between(poses[a], poses[b])
            if injected:
                # A place-recognition false positive: "b is where a was", give or take.
                guess = self._noise.normal(size=3) * [0.3, 0.3, math.radians(5.0)]
            edges.append(self._match("loop", a, b, guess, injected))
        self.validate(edges)
        kept = [e for e in edges if e.kept]
        for e in kept:
            self.estimate.add_edge(graph_edge(e, self.graph))
        self.edges.extend(edges)
        if kept:
            self.estimate.update(extra_iterations=2)
