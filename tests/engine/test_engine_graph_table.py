"""The engine's graph table: padded in-neighbour slots of every episode's graphs, and the graph of each interval."""

from __future__ import annotations

import numpy as np

from fxc_env import ConsensusEngine, make_config
from fxc_env.core.graphs import random_topology
from fxc_env.engine.backend import NumpyBackend
from fxc_env.engine.clock import InstantTables, LockStepClock
from fxc_env.engine.graph_table import GraphTable


def in_neighbours(edges, i):
    return sorted(int(j) for j, r in edges if r == i)


def test_rows_are_the_topologys_in_neighbours_padded_with_the_agent_itself():
    topology = random_topology(30, seed=4, mean_in_degree=2.5, period=3)
    table = GraphTable([topology], topology.max_in_degree + 2, NumpyBackend("float64", 1), False)
    for g in range(topology.period):
        for i in range(30):
            mask = table.mask_features[g, i].astype(bool)
            assert sorted(table.neighbour_index[g, i][mask].tolist()) == in_neighbours(topology.edges[g], i)
            assert np.all(table.neighbour_index[g, i][~mask] == i)  # a padded gather is an exact zero row


def test_periodic_draw_is_k_mod_m_and_episodes_keep_their_own_topology():
    first, second = random_topology(12, seed=1, period=2), random_topology(12, seed=2, period=3)
    config = make_config(topology=first)
    backend = NumpyBackend("float64", 3)
    table = GraphTable([first, second, first], 6, backend, False)
    assert not table.shared
    clock = LockStepClock(InstantTables(make_config(topology=first, n_intervals=10), backend))
    for k in range(7):
        clock.k = k
        table.draw(clock, switching_draw=None)
        np.testing.assert_array_equal(table.graph_indices(), [k % 2, k % 3, k % 2])
    assert config.topology is first


def test_the_blocks_of_the_fast_path_cover_every_agent_once_slot_major():
    topology = random_topology(1000, seed=3, mean_in_degree=4.0)
    table = GraphTable([topology], topology.max_in_degree, NumpyBackend("float64", 1), False)
    pieces = table.blocks(0, 384)
    assert [start for start, _, _ in pieces] == [0, 384, 768]
    index = np.concatenate([block for _, block, _ in pieces], axis=1)
    mask = np.concatenate([block for _, _, block in pieces], axis=1)
    np.testing.assert_array_equal(index, table.neighbour_index[0].T)
    np.testing.assert_array_equal(mask, table.mask_features[0].T)


def test_gathered_rows_are_the_in_neighbours_states():
    config = make_config("random_20_planar", n_intervals=5)
    engine = ConsensusEngine(config)
    x0, v0 = engine.sample_initial_state(np.random.default_rng(0))
    engine.reset(x0[None], v0[None])
    rows, mask = engine.graphs.gather(engine.state)
    edges = config.topology.edges[0]
    for i in range(20):
        for slot, j in enumerate(in_neighbours(edges, i)):
            np.testing.assert_array_equal(rows[0, i, slot], engine.state[0, j])
            assert mask[i, slot] == 1.0
