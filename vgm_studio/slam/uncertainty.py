"""How uncertain the graph is about one keyframe seen from another: Dijkstra projection.

The relative covariance of two keyframes is bounded by composing the covariances of the edges
along the most certain path between them (the "Dijkstra projection" of Bosse et al. 2003,
Atlas, and Olson 2008): along an unclosed corridor it grows with every edge, and a closed loop
gives a shortcut that shrinks it again. It ignores what parallel paths add, so it errs on the
wide side, which is the safe side for a search window. Each edge counts its translational
variance, its rotational variance, and its length; a heading error at one edge moves the far
end by its lever arm, so over a path of length L with rotational variance Vθ the position
variance grows by Vθ·L²/3 (the sum over a straight chain of equal steps).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.special import chdtri

from vgm_studio.core.compiled import kernel
from vgm_studio.graph.pose_graph import GraphEdge

# A heading error acts over metres before the next loop: this lever ranks paths by the
# position error they cause (it only chooses the path; the variances are summed exactly).
_LEVER = 5.0


def chi2_gate(probability: float, dof: int) -> float:
    """The χ² value with ``dof`` degrees of freedom below which ``probability`` of its mass
    lies: a Mahalanobis gate. (``scipy.special``'s inverse, not ``scipy.stats``, whose
    import alone costs every run 0.4 s.)"""
    return float(chdtri(dof, 1.0 - probability))


@dataclass(frozen=True)
class Relative:
    """Uncertainty of every keyframe relative to one source keyframe.

    Attributes:
        position_var: (K,) isotropic position variance, m² (inf where unreachable).
        heading_var: (K,) heading variance, rad².
    """

    position_var: NDArray[np.float64]
    heading_var: NDArray[np.float64]


class UncertaintyGraph:
    """The kept edges' variances and lengths, searched for the most certain paths."""

    def __init__(self) -> None:
        self._a: list[int] = []
        self._b: list[int] = []
        self._vt: list[float] = []
        self._vr: list[float] = []
        self._len: list[float] = []
        self._count = 1
        # Each source's answer until the next edge: a check asks for the same sources more
        # than once (an audit's group check asks one graph as the graph and as the drift).
        self._known: dict[tuple[int, int], Relative] = {}

    def add(self, edge: GraphEdge) -> None:
        """Adds a kept edge (sequential, odometry or loop)."""
        cov = np.asarray(edge.covariance, dtype=np.float64)
        if not np.all(np.isfinite(cov)):
            raise ValueError(f"edge {edge.a}→{edge.b} has a covariance that is not finite")
        self._a.append(edge.a)
        self._b.append(edge.b)
        self._vt.append(float(cov[0, 0] + cov[1, 1]) / 2.0)
        self._vr.append(float(cov[2, 2]))
        self._len.append(float(np.hypot(edge.measurement[0], edge.measurement[1])))
        self._count = max(self._count, edge.a + 1, edge.b + 1)
        self._known.clear()

    def relative(self, sources: NDArray[np.int64] | list[int], count: int) -> list[Relative]:
        """Uncertainty of keyframes ``0..count-1`` relative to each source."""
        missing = sorted({int(s) for s in sources} - {s for s, c in self._known if c == count})
        if missing:
            found = self._search(missing, count)
            self._known.update(((s, count), r) for s, r in zip(missing, found, strict=True))
        return [self._known[(int(s), count)] for s in sources]

    def _search(self, sources: list[int], count: int) -> list[Relative]:
        n = max(count, self._count)
        a0, b0 = np.array(self._a, dtype=np.int64), np.array(self._b, dtype=np.int64)
        vt0, vr0 = np.array(self._vt), np.array(self._vr)
        weight0 = vt0 + vr0 * _LEVER**2 + 1e-12
        lo, hi = np.minimum(a0, b0), np.maximum(a0, b0)
        # Keep the most certain of parallel edges (csgraph would sum duplicates).
        order = np.lexsort((weight0, lo, hi))
        first = np.ones(len(order), dtype=bool)
        first[1:] = (lo[order][1:] != lo[order][:-1]) | (hi[order][1:] != hi[order][:-1])
        keep = order[first]
        a, b, weight = a0[keep], b0[keep], weight0[keep]
        vt, vr, ln = vt0[keep], vr0[keep], np.array(self._len)[keep]
        graph = coo_matrix((weight, (a, b)), shape=(n, n)).tocsr()
        dist, pred = dijkstra(graph, directed=False, indices=sources, return_predecessors=True)
        # A tree edge's row of ``values`` is found by its two ends' key among the sorted keys
        # (row 0 is zeros: the source's and unreached nodes' own "edge").
        keys = np.minimum(a, b) * n + np.maximum(a, b)
        order = np.argsort(keys)
        values = np.vstack([np.zeros((1, 3)), np.column_stack([vt, vr, ln])[order]])
        ordered = keys[order]
        return [_accumulate(d, p, ordered, values, count) for d, p in zip(dist, pred, strict=True)]


def _accumulate(
    dist: NDArray[np.float64],
    pred: NDArray[np.int32],
    keys: NDArray[np.int64],
    values: NDArray[np.float64],
    count: int,
) -> Relative:
    """Sums each edge's variances and length from the source down the shortest-path tree."""
    n = len(dist)
    nodes = np.arange(n)
    reach = np.isfinite(dist)
    parent = np.where(reach & (pred >= 0), pred, nodes)
    acc = _path_sums(parent, keys, values)
    acc[~reach] = np.inf
    t, r, length = acc[:count, 0], acc[:count, 1], acc[:count, 2]
    with np.errstate(invalid="ignore"):
        position = np.where(np.isfinite(t), t + r * length**2 / 3.0, np.inf)
    return Relative(position, r)


@kernel
def _path_sums(parent: Any, keys: Any, values: Any) -> Any:
    """Each node's (translational, rotational, length) sums over its path to the root of
    ``parent``'s forest (a root is its own parent and sums zeros). A node's own edge is found
    by its key ``lo·n + hi`` among the sorted ``keys`` (its row of ``values``, one past row 0
    of zeros); each sum is its parent's plus that edge, so every node costs one addition.

    A third of an audit's group check on the Killian Court graph was these sums, found by
    pointer jumping in numpy (log2(n) passes over every node): 0.4-0.5 ms a source, and
    0.16 compiled; walked down the tree, 0.07.
    """
    n = len(parent)
    acc = np.empty((n, values.shape[1]))
    done = np.zeros(n, np.bool_)
    path = np.empty(n, np.int64)
    for v in range(n):
        # Up to the first node already summed (or a root), then down again.
        depth, u = 0, v
        while not done[u] and parent[u] != u:
            # Compiled code checks no bounds: a parent out of range or a cycle (a path
            # longer than the forest has nodes) would write past the arrays, not raise.
            if depth == n or not 0 <= parent[u] < n:
                raise ValueError("parent is not a forest over its nodes")
            path[depth] = u
            depth += 1
            u = parent[u]
        if not done[u]:
            acc[u, :] = 0.0
            done[u] = True
        while depth > 0:
            depth -= 1
            w = path[depth]
            p = parent[w]
            key = min(p, w) * n + max(p, w)
            row = np.searchsorted(keys, key) + 1
            if row > len(keys) or keys[row - 1] != key:
                raise ValueError("a tree edge is not among the keys")
            for k in range(values.shape[1]):
                acc[w, k] = acc[p, k] + values[row, k]
            done[w] = True
    return acc
