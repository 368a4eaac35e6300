"""Topologies: generators, neighbour arrays, W, xi and validation (the paper's Section 2; docs: environment.md, "The environment")."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
from helpers import (
    PAPER_GRAPHS,
    PAPER_XI,
    adjacency_by_hand,
    averaging_matrix_by_hand,
    has_spanning_tree,
    left_perron_vector,
    reachable_from,
)

from fxc_env import Topology, make_topology
from fxc_env.core.graphs import TOPOLOGY_NAMES


def edge_set(array) -> set[tuple[int, int]]:
    return {(int(j), int(i)) for j, i in array}


# ------------------------------------------------------------------ generators
@pytest.mark.parametrize("n", [2, 3, 6, 11])
def test_ring_edges(n):
    topo = make_topology("ring", n)
    assert topo.period == 1
    assert edge_set(topo.edges[0]) == {(i, (i + 1) % n) for i in range(n)}
    assert has_spanning_tree(n, topo.edges[0])


@pytest.mark.parametrize("n", [2, 3, 6, 11])
def test_path_edges_form_a_spanning_tree_rooted_at_0(n):
    topo = make_topology("path", n)
    assert edge_set(topo.edges[0]) == {(i, i + 1) for i in range(n - 1)}
    assert reachable_from(n, topo.edges[0], 0) == set(range(n))


@pytest.mark.parametrize("n", [2, 3, 6, 11])
def test_star_is_led_by_agent_0(n):
    topo = make_topology("star", n)
    assert edge_set(topo.edges[0]) == {(0, i) for i in range(1, n)}
    expected = np.zeros(n)
    expected[0] = 1.0
    np.testing.assert_allclose(topo.consensus_weights(), expected, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3, 6])
def test_complete_edges(n):
    topo = make_topology("complete", n)
    assert edge_set(topo.edges[0]) == {(j, i) for j in range(n) for i in range(n) if i != j}
    np.testing.assert_allclose(topo.consensus_weights(), np.full(n, 1 / n), rtol=1e-12)


def test_named_topologies_default_to_six_agents():
    for name in TOPOLOGY_NAMES:
        assert make_topology(name).n_agents == 6


def test_paper_fig1_is_the_assumed_reconstruction_of_the_readme():
    topo = make_topology("paper_fig1")
    assert topo.period == 3
    for g, expected in enumerate(PAPER_GRAPHS):
        assert edge_set(topo.edges[g]) == set(expected)
        assert not has_spanning_tree(6, expected)  # no graph alone spans
    union = [e for graph in PAPER_GRAPHS for e in graph]
    assert has_spanning_tree(6, union)
    assert "assumed" in topo.note


def test_paper_fig1_needs_six_agents():
    with pytest.raises(ValueError, match="n_agents"):
        make_topology("paper_fig1", 5)


def test_unknown_name_is_rejected():
    with pytest.raises(ValueError, match="topology"):
        make_topology("hexagon")


# ---------------------------------------------------------------------- random
@pytest.mark.parametrize("period", [1, 2, 3])
def test_random_is_seeded(period):
    a = make_topology("random", 15, seed=7, period=period)
    b = make_topology("random", 15, seed=7, period=period)
    assert a.period == b.period == period
    for ea, eb in zip(a.edges, b.edges, strict=True):
        np.testing.assert_array_equal(ea, eb)
    others = [make_topology("random", 15, seed=s, period=period) for s in range(8, 12)]
    assert any(edge_set(np.concatenate(o.edges)) != edge_set(np.concatenate(a.edges)) for o in others)


@pytest.mark.parametrize("period", [1, 2, 3, 5])
@pytest.mark.parametrize("n", [2, 3, 8, 40])
def test_random_union_always_spans(n, period):
    for seed in range(25):
        topo = make_topology("random", n, seed=seed, period=period)
        union = np.concatenate(topo.edges)
        assert has_spanning_tree(n, union), (n, period, seed)
        assert np.all(union[:, 0] != union[:, 1])  # no self-loops
        assert len(edge_set(union)) == len(union)  # no edge twice in the period


@pytest.mark.parametrize("n", [5, 20, 60])
def test_random_in_degrees_are_near_the_mean(n):
    # Every in-degree is floor or ceil of mean_in_degree (the observation width stays small).
    for seed in range(10):
        topo = make_topology("random", n, seed=seed, mean_in_degree=2.5)
        degrees = np.bincount(topo.edges[0][:, 1], minlength=n)
        assert set(degrees.tolist()) <= {2, 3}
        assert topo.max_in_degree <= 3


@pytest.mark.parametrize("n", [5, 20, 60])
def test_random_reaches_the_mean_in_degree(n):
    for seed in range(10):
        topo = make_topology("random", n, seed=seed, mean_in_degree=2.0)
        assert len(topo.edges[0]) == round(2.0 * n)


# ----------------------------------------------------------- neighbour arrays
def check_neighbour_arrays(topo: Topology) -> None:
    index, mask = topo.neighbour_index, topo.neighbour_mask
    d_max = max(int(np.bincount(e[:, 1], minlength=topo.n_agents).max(initial=0)) for e in topo.edges)
    assert topo.max_in_degree == d_max
    assert index.shape == mask.shape == (topo.period, topo.n_agents, d_max)
    for g, edges in enumerate(topo.edges):
        for i in range(topo.n_agents):
            senders = sorted(int(j) for j, r in edges if r == i)
            real = index[g, i][mask[g, i]]
            assert list(real) == senders  # ascending in-neighbours of G_g
            assert topo.in_degree[g, i] == len(senders)
            assert np.all(mask[g, i, : len(senders)]) and not np.any(mask[g, i, len(senders) :])
            assert np.all(index[g, i][~mask[g, i]] == i)  # padding points at the agent itself


@pytest.mark.parametrize(
    "topo",
    [
        make_topology("paper_fig1"),
        make_topology("ring", 5),
        make_topology("complete", 4),
        make_topology("star", 7),
        make_topology("random", 25, seed=3),
        make_topology("random", 25, seed=4, period=3),
    ],
    ids=lambda t: t.name,
)
def test_neighbour_index_and_mask_match_the_edges(topo):
    check_neighbour_arrays(topo)


# --------------------------------------------------------------- W, L and xi
@pytest.mark.parametrize(
    "topo",
    [
        make_topology("paper_fig1"),
        make_topology("path", 5),
        make_topology("random", 12, seed=1),
        make_topology("random", 12, seed=2, period=3, mean_in_degree=3.0),
    ],
    ids=lambda t: t.name,
)
def test_averaging_matrix_matches_the_dense_definition(topo):
    n = topo.n_agents
    for g, edges in enumerate(topo.edges):
        a = adjacency_by_hand(n, edges)
        np.testing.assert_array_equal(topo.adjacency(g).toarray(), a)
        np.testing.assert_allclose(topo.laplacian(g).toarray(), np.diag(a.sum(axis=1)) - a, atol=0)
        w = topo.averaging_matrix(g).toarray()
        np.testing.assert_allclose(w, averaging_matrix_by_hand(n, edges), rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-14)
        assert np.all(w >= 0)


def test_paper_xi_from_the_ordered_product_built_by_hand():
    topo = make_topology("paper_fig1")
    w0, w1, w2 = (averaging_matrix_by_hand(6, g) for g in PAPER_GRAPHS)
    product = w2 @ w1 @ w0  # G_0 is used first
    np.testing.assert_allclose(topo.period_product(), product, rtol=1e-14, atol=1e-15)
    xi = left_perron_vector(product)
    np.testing.assert_allclose(xi, PAPER_XI, atol=1e-12)
    np.testing.assert_allclose(topo.consensus_weights(), xi, atol=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_xi_is_the_left_perron_vector_of_w_for_a_fixed_random_graph(seed):
    topo = make_topology("random", 9, seed=seed)
    w = averaging_matrix_by_hand(9, topo.edges[0])
    xi = topo.consensus_weights()
    assert xi.sum() == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(xi @ w, xi, atol=1e-12)
    np.testing.assert_allclose(xi, left_perron_vector(w), atol=1e-10)


def test_union_is_the_joint_graph():
    topo = make_topology("paper_fig1")
    union = adjacency_by_hand(6, [e for graph in PAPER_GRAPHS for e in graph])
    np.testing.assert_array_equal(topo.union().toarray(), union)


# ------------------------------------------------------------ input formats
def test_networkx_digraph_equals_edge_list():
    edges = [(0, 1), (1, 2), (2, 0), (0, 3), (3, 2)]
    from_list = make_topology(edges)
    from_graph = make_topology(nx.DiGraph(edges))
    assert from_list.n_agents == from_graph.n_agents == 4
    np.testing.assert_array_equal(from_list.edges[0], from_graph.edges[0])
    assert edge_set(from_list.edges[0]) == set(edges)


def test_list_of_digraphs_equals_a_period_of_edge_lists():
    period = [[(0, 1), (3, 4)], [(1, 2), (4, 5)], [(2, 3), (5, 0)]]
    graphs = []
    for edges in period:
        graph = nx.DiGraph()
        graph.add_nodes_from(range(6))
        graph.add_edges_from(edges)
        graphs.append(graph)
    from_lists = make_topology(period)
    from_graphs = make_topology(graphs)
    named = make_topology("paper_fig1")
    for a, b, c in zip(from_lists.edges, from_graphs.edges, named.edges, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)


def test_numpy_edge_array_and_explicit_n_agents():
    topo = make_topology(np.array([[0, 1], [1, 2]]), n_agents=3)
    assert topo.n_agents == 3
    assert edge_set(topo.edges[0]) == {(0, 1), (1, 2)}


def test_undirected_networkx_graph_is_rejected():
    with pytest.raises(ValueError, match="topology"):
        make_topology(nx.Graph([(0, 1), (1, 2)]))


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize(
    ("edges", "n", "pattern"),
    [
        ([(0, 1), (1, 1)], 3, r"topology.*self-loop"),
        ([(0, 1), (1, 3)], 3, r"topology.*outside"),
        ([(0, 1), (-1, 2)], 3, r"topology.*outside"),
        ([(0, 1), (0, 2), (0, 1)], 3, r"topology.*more than once"),
        ([(0, 1), (0.5, 2)], 3, r"topology.*integer"),
        ([(0, 1, 2)], 3, r"topology"),
    ],
)
def test_malformed_edges_name_the_argument(edges, n, pattern):
    with pytest.raises(ValueError, match=pattern):
        make_topology(edges, n_agents=n)


def test_missing_spanning_tree_names_the_unreachable_agents():
    # Agent 2 hears nobody and nobody hears it: agent 0 reaches {0, 1} only.
    with pytest.raises(ValueError, match=r"topology.*spanning tree.*agents \[2\]"):
        make_topology([(0, 1)], n_agents=3)


def test_missing_joint_spanning_tree_names_the_unreachable_agents():
    with pytest.raises(ValueError, match=r"topology.*union.*agents \[3, 4\]"):
        make_topology([[(0, 1)], [(1, 2)], [(3, 4)]], n_agents=5)


def test_two_roots_report_a_consistent_unreachable_set():
    # Two separate chains: whichever root is reported, the listed agents are exactly
    # those it cannot reach.
    edges = [(0, 1), (1, 2), (3, 4)]
    with pytest.raises(ValueError, match="topology") as info:
        make_topology(edges, n_agents=5)
    message = str(info.value)
    root = int(message.split("agent ")[1].split(",")[0])
    listed = message.split("agents [")[1].split("]")[0]
    unreachable = {int(a) for a in listed.split(", ")}
    assert unreachable == set(range(5)) - reachable_from(5, edges, root)


@pytest.mark.parametrize("bad", [0, -2, 2.5, True])
def test_bad_n_agents_is_rejected(bad):
    with pytest.raises(ValueError, match="n_agents"):
        make_topology("ring", bad)


def test_topology_without_edges_needs_n_agents():
    with pytest.raises(ValueError, match="n_agents"):
        make_topology([[]])
