"""The largest clique's size against networkx's exact search."""

from __future__ import annotations

import networkx as nx
import pytest

from vgm_studio.core.cliques import largest_clique_size


@pytest.mark.parametrize("density", [0.05, 0.3, 0.6, 0.9, 0.97])
def test_largest_clique_size_is_networkxs_on_random_graphs(density):
    sizes = []
    for seed in range(40):
        graph = nx.gnp_random_graph(5 + seed, density, seed=seed)
        want = len(nx.max_weight_clique(graph, weight=None)[0])
        assert largest_clique_size(graph.nodes, graph.edges) == want, seed
        sizes.append(want)
    assert max(sizes) >= 3  # cliques were there to find


def test_no_vertex_self_loops_and_edges_to_strangers():
    assert largest_clique_size([], []) == 0
    assert largest_clique_size(["a"], [("a", "a")]) == 1
    # The triangle's third edge goes to a vertex not in the graph: a pair is all there is.
    assert largest_clique_size(["a", "b", "c"], [("a", "b"), ("b", "d"), ("a", "d")]) == 2
    assert largest_clique_size("abcd", [(u, v) for u in "abcd" for v in "abcd"]) == 4
    assert largest_clique_size(["a", "a", "b"], [("a", "b")]) == 2  # listed twice, one vertex


def test_a_clique_deeper_than_pythons_recursion_limit():
    """A hostile graph's thousand-vertex clique: networkx's recursive search raised
    RecursionError on it; the search here keeps its own stack."""
    graph = nx.complete_graph(1200)
    graph.remove_edge(0, 1)
    assert largest_clique_size(graph.nodes, graph.edges) == 1199
