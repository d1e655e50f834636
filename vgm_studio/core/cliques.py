"""The size of a graph's largest clique, exactly, with vertex sets as bitsets.

networkx's ``max_weight_clique`` asks ``has_edge`` once per pair it looks at: on the dense
support graphs of a corridor's loops that was 460,000 calls and 1.5 s of an Intel SLAM run.
Here a vertex's neighbours are one Python int, and a branch's candidates one AND: Tomita and
Seki's MCQ, each branch bounded by a greedy colouring of its candidates (a set coloured with
k colours holds no clique of more than k vertices).
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable


def largest_clique_size(
    nodes: Iterable[Hashable], edges: Iterable[tuple[Hashable, Hashable]]
) -> int:
    """The number of vertices in a largest clique of the graph (0 for no vertex); edges to a
    vertex not in ``nodes`` and self-loops are left out."""
    index: dict[Hashable, int] = {}
    for v in nodes:  # a vertex listed twice is one vertex
        index.setdefault(v, len(index))
    neighbours = [0] * len(index)
    for u, v in edges:
        if u != v and u in index and v in index:
            neighbours[index[u]] |= 1 << index[v]
            neighbours[index[v]] |= 1 << index[u]
    # Depth first with an explicit stack, not recursion: a clique of a thousand vertices
    # (a hostile graph's) would pass Python's recursion limit, as networkx's search did.
    best = 0
    stack = [(0, (1 << len(index)) - 1, *_coloured((1 << len(index)) - 1, neighbours))]
    while stack:
        size, candidates, order, colours = stack.pop()
        if not candidates:
            best = max(best, size)
            continue
        # The last vertex coloured first: its colour bounds what it and the rest can add.
        v, colour = order.pop(), colours.pop()
        if size + colour <= best:
            continue
        stack.append((size, candidates & ~(1 << v), order, colours))
        inner = candidates & neighbours[v]
        stack.append((size + 1, inner, *_coloured(inner, neighbours)))
    return best


def _coloured(candidates: int, neighbours: list[int]) -> tuple[list[int], list[int]]:
    """The candidates in colour classes, greedily: each class a set of mutually non-adjacent
    vertices; each vertex with its class's number, classes in order."""
    order: list[int] = []
    colours: list[int] = []
    colour = 0
    left = candidates
    while left:
        colour += 1
        free = left
        while free:
            v = (free & -free).bit_length() - 1
            free &= ~neighbours[v] & ~(1 << v)
            left &= ~(1 << v)
            order.append(v)
            colours.append(colour)
    return order, colours
