"""False loops put into a graph on purpose, to measure how many of them an audit flags.

Each is a place-recognition false positive as another SLAM would make one: two vertices that
are far apart in the graph's own optimised estimate, and a measurement that says "b is where
a was, give or take" (a guess within 0.3 m and 5°), refined by the scan matcher so that the
scans line up as well as they can there: the plausible measurement a front end would
report, between places that are not the same (the style of Sünderhauf and Protzel's
robustness tests, and of ``slam --inject-false-loops``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from vgm_studio.audit.config import InjectConfig
from vgm_studio.datasets.g2o import G2oEdge
from vgm_studio.datasets.scans import Scan
from vgm_studio.matching.matcher import ScanMatcher

_GUESS_SIGMA = np.array([0.3, 0.3, math.radians(5.0)])


def false_loops(
    poses: NDArray[np.float64],
    edges: Sequence[G2oEdge],
    scans: Sequence[Scan],
    config: InjectConfig,
    matcher: ScanMatcher | None = None,
) -> list[G2oEdge]:
    """``config.count`` wrong loop edges between vertices at least ``min_distance`` apart.

    Args:
        poses: (V, 3) the graph's estimate (optimised from its own edges).
        edges: The graph's edges: a pair it already joins is not drawn, and its loops'
            median information weights the new ones (its sequential edges' if it has none).
        scans: One per vertex, to refine each measurement on.
        config: How many, the seed, and how far apart.
        matcher: The scan matcher (one is made if not given).
    """
    if config.count <= 0:
        return []
    rng = np.random.default_rng([config.seed, 51])
    matcher = matcher or ScanMatcher()
    joined = {(min(e.a, e.b), max(e.a, e.b)) for e in edges}
    info = _typical_information(edges)
    count = len(poses)
    out: list[G2oEdge] = []
    for _ in range(200 * config.count):
        if len(out) >= config.count or count <= config.min_gap:
            break
        b = int(rng.integers(config.min_gap, count))
        a = int(rng.integers(0, b - config.min_gap + 1))
        far = math.dist(poses[a, :2], poses[b, :2]) >= config.min_distance
        if not far or (a, b) in joined:
            continue
        joined.add((a, b))
        guess = rng.normal(size=3) * _GUESS_SIGMA
        match = matcher.match(scans[a], scans[b], guess)
        measurement = match.estimate if match.converged else guess
        out.append(G2oEdge(a, b, np.asarray(measurement, dtype=np.float64), info))
    return out


def _typical_information(edges: Sequence[G2oEdge]) -> NDArray[np.float64]:
    loops = [e.information for e in edges if abs(e.a - e.b) != 1]
    chosen = loops or [e.information for e in edges]
    if not chosen:
        return np.diag([100.0, 100.0, 1000.0])
    return np.asarray(np.median(np.stack(chosen), axis=0), dtype=np.float64)
