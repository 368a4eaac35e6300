"""The graph as edge tensors (docs: graph-tensors.md, "Graph tensors"): edges, features, padding, switching, backends."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fxc_env import ConsensusEngine, ReferencePolicy, make_config
from fxc_env.engine.graph_tensors import (
    GRAPH_TENSOR_KEYS,
    edge_capacity,
    edge_feature_size,
    episode_graph,
    graph_tensors,
)

FAMILY = {"family": "random", "mean_in_degree": (1.5, 3.0), "period": (1, 3)}


def started(config, b=3, device=None, seed=0):
    engine = ConsensusEngine(config, b, device=device)
    x0, v0, u_max, topologies = engine.draw_batch(np.random.default_rng(seed))
    engine.reset(x0, v0, u_max=u_max, topologies=topologies)
    return engine


def host(tensors):
    return [np.asarray(t) if isinstance(t, np.ndarray) else t.cpu().numpy() for t in tensors]


def dense(edge_index, n_edges, n):
    """``A[i, j] = 1`` for every listed edge j -> i (duplicates counted)."""
    a = np.zeros((n, n))
    np.add.at(a, (edge_index[1, :n_edges], edge_index[0, :n_edges]), 1.0)
    return a


def check_against_graphs(engine, tensors):
    """Edges are the adjacency of each episode's current graph; features are its observation rows."""
    edge_index, edge_mask, n_edges, edge_attr = host(tensors)
    obs = np.asarray(engine.observations())
    rows, _, _ = engine.layout.split(obs)
    rows = rows.reshape(*rows.shape[:3], -1)  # (B, N, slots, F)
    graphs = engine.graph_indices()
    for b, topology in enumerate(engine.topologies):
        g = int(graphs[b])
        n = topology.n_agents
        assert n_edges[b] == len(topology.edges[g])
        np.testing.assert_array_equal(dense(edge_index[b], n_edges[b], n), topology.adjacency(g).toarray())
        for e in range(n_edges[b]):
            j, i = edge_index[b, :, e]
            slot = list(topology.neighbour_index[g, i][topology.neighbour_mask[g, i]]).index(j)
            np.testing.assert_array_equal(edge_attr[b, e], rows[b, i, slot])
        assert edge_mask[b].sum() == n_edges[b] and edge_mask[b, : n_edges[b]].all()


@pytest.mark.parametrize(
    "settings",
    [
        {"scenario": "paper_fig1"},
        {"scenario": "paper_fig1", "obs_mode": "raw", "dim": 2},
        {"topology": FAMILY, "n_agents": 7, "obs_slots": 6},
        {"topology": "random", "n_agents": 9, "topology_period": 3, "switching": "random", "obs_noise": 0.05},
        {"topology": "complete", "n_agents": 5, "agent_model": {"name": "integrator_chain", "order": 3}},
    ],
)
def test_edges_are_the_current_graph_and_features_are_its_observation_rows(settings):
    config = make_config(**settings)
    engine = started(config)
    policy = ReferencePolicy(config)
    for _ in range(7):
        tensors = graph_tensors(engine)
        assert tensors.edge_attr.shape[-1] == edge_feature_size(config) == config.n_states * config.dim
        check_against_graphs(engine, tensors)
        engine.step(policy.act(engine.observations()))


def test_edge_index_follows_pyg_convention_source_then_target():
    # A path 0 -> 1 -> 2: agent 1 measures 0, agent 2 measures 1.
    engine = started(make_config(topology=[(0, 1), (1, 2)], n_agents=3), b=1)
    edge_index, _, n_edges, edge_attr = host(graph_tensors(engine))
    assert n_edges.tolist() == [2]
    np.testing.assert_array_equal(edge_index[0], [[0, 1], [1, 2]])
    x, v = np.asarray(engine.x)[0, :, 0], np.asarray(engine.v)[0, :, 0]
    raw = started(make_config(topology=[(0, 1), (1, 2)], n_agents=3, obs_mode="raw"), b=1)
    raw.reset(engine.x, engine.v)
    _, _, _, raw_attr = host(graph_tensors(raw))
    np.testing.assert_allclose(raw_attr[0], [[x[0] - x[1], v[0] - v[1]], [x[1] - x[2], v[1] - v[2]]], rtol=0, atol=0)
    assert np.abs(edge_attr).max() <= 1.0  # normalized rows


def test_switching_follows_the_schedule_s_period():
    config = make_config("paper_fig1")  # three graphs, G_{k mod 3}
    topology = config.topology
    engine = started(config, b=2)
    policy = ReferencePolicy(config)
    for k in range(2 * topology.period + 1):
        edge_index, _, n_edges, _ = host(graph_tensors(engine))
        for b in range(2):
            np.testing.assert_array_equal(edge_index[b, :, : n_edges[b]].T, topology.edges[k % topology.period])
        engine.step(policy.act(engine.observations()))


def test_padding_is_the_extra_node_n_with_zero_features():
    config = make_config(topology=FAMILY, n_agents=8)
    engine = started(config, b=6, seed=3)
    edge_index, edge_mask, n_edges, edge_attr = host(graph_tensors(engine))
    width = max(len(edges) for topology in engine.topologies for edges in topology.edges)
    assert edge_index.shape == (6, 2, width) and edge_mask.shape == (6, width) and n_edges.shape == (6,)
    assert len(set(n_edges.tolist())) > 1  # the episodes' graphs differ in size: some rows are padded
    for b in range(6):
        assert not edge_mask[b, n_edges[b] :].any()
        # Padding is the edge N -> N (one past the last agent), never an edge between agents.
        assert (edge_index[b, :, n_edges[b] :] == 8).all() and (edge_attr[b, n_edges[b] :] == 0).all()
        assert (edge_index[b, :, : n_edges[b]] < 8).all()
    assert edge_index.dtype == np.int64 and edge_mask.dtype == bool and n_edges.dtype == np.int64


def test_dropped_links_are_not_listed():
    config = make_config(topology="complete", n_agents=6, link_dropout=0.4)
    engine = started(config, b=4, seed=1)
    edge_index, edge_mask, n_edges, edge_attr = host(graph_tensors(engine))
    _, mask, _ = engine.layout.split(np.asarray(engine.observations()))
    assert (n_edges == mask.reshape(4, -1).sum(axis=1)).all() and (n_edges < 30).any()
    for b in range(4):
        received = {
            (int(j), i)
            for i in range(6)
            for j, m in zip(engine.topologies[b].neighbour_index[0, i], mask[b, i], strict=True)
            if m
        }
        assert {tuple(pair) for pair in edge_index[b, :, : n_edges[b]].T.tolist()} == received
        assert edge_mask[b].sum() == n_edges[b] and (edge_index[b, :, n_edges[b] :] == 6).all()
        assert (edge_attr[b, n_edges[b] :] == 0).all()


@pytest.mark.parametrize("settings", [{"scenario": "paper_fig1", "dim": 2}, {"topology": FAMILY, "n_agents": 6}])
def test_numpy_and_torch_give_the_same_tensors(settings):
    config = make_config(**settings)
    numpy_engine = started(config, b=4, seed=2)
    torch_engine = ConsensusEngine(config, 4, device="cpu")
    torch_engine.reset(
        torch.as_tensor(np.asarray(numpy_engine.x)),
        torch.as_tensor(np.asarray(numpy_engine.v)),
        topologies=numpy_engine.topologies,
    )
    policy = ReferencePolicy(config)
    for _ in range(4):
        a, b = graph_tensors(numpy_engine), graph_tensors(torch_engine)
        assert all(isinstance(t, torch.Tensor) for t in b)
        for name, left, right in zip(GRAPH_TENSOR_KEYS, host(a), host(b), strict=True):
            assert left.dtype == right.dtype, name
            np.testing.assert_allclose(left, right, rtol=1e-12, atol=1e-15, err_msg=name)
        numpy_engine.step(policy.act(numpy_engine.observations()))
        torch_engine.step(policy.act(torch_engine.observations()))


def test_torch_tensors_stay_on_the_device_without_host_reads():
    config = make_config(topology=FAMILY, n_agents=6, link_dropout=0.2)
    engine = started(config, b=5, device="meta")  # meta: any read of a value would fail
    tensors = graph_tensors(engine)
    assert all(t.device.type == "meta" for t in tensors)
    assert tensors.edge_attr.shape[:2] == tensors.edge_mask.shape


def test_given_observations_set_the_feature_dtype():
    engine = started(make_config("paper_fig1"), b=2)
    obs = engine.observations().astype(np.float32)
    tensors = graph_tensors(engine, obs)
    assert tensors.edge_attr.dtype == np.float32
    edge_index, edge_attr = episode_graph(tensors, 1)
    assert edge_index.shape == (2, int(tensors.n_edges[1])) and edge_attr.shape == (int(tensors.n_edges[1]), 2)


# ------------------------------------------------------------------ the TorchRL environment


def torchrl_env(**settings):
    from fxc_env import ConsensusTorchEnv

    return ConsensusTorchEnv(graph_tensors=True, seed=0, **settings)


@pytest.mark.parametrize(
    "settings",
    [
        {"scenario": "paper_fig1", "batch_size": 3},
        {"scenario": "generalist", "batch_size": 4},
        {"topology": FAMILY, "n_agents": 5, "batch_size": 3, "link_dropout": 0.3, "obs_mode": "raw", "dim": 2},
    ],
)
def test_torchrl_env_specs_hold_with_graph_tensors(settings):
    from torchrl.envs.utils import check_env_specs

    env = torchrl_env(**settings)
    check_env_specs(env)
    for key in GRAPH_TENSOR_KEYS:
        assert key in env.observation_spec.keys()


def test_torchrl_env_adds_the_graph_at_reset_and_every_step_with_the_card_s_shapes():
    from fxc_env import reference_policy

    env = torchrl_env(scenario="paper_fig1", batch_size=2, dim=2)
    rollout = env.rollout(4, reference_policy(env))
    b, n, e = 2, 6, env.n_edges_max
    assert e == max(len(edges) for edges in env.config.topology.edges)
    topology = env.config.topology
    for k, td in ((0, rollout[:, 0]), (3, rollout[:, 3]), (4, rollout["next"][:, 3])):
        assert td["edge_index"].shape == (b, 2, e) and td["edge_index"].dtype == torch.int64
        assert td["edge_mask"].shape == (b, e) and td["edge_mask"].dtype == torch.bool
        assert td["n_edges"].shape == (b,) and td["n_edges"].dtype == torch.int64
        assert td["edge_attr"].shape == (b, e, 2 * 2) and td["edge_attr"].dtype == torch.float64
        # Features are the observation's rows of the edge's target and slot.
        rows, _, _ = env.config.layout.split(td["agents", "observation"].numpy())
        for episode in range(b):
            for edge in range(int(td["n_edges"][episode])):
                j, i = td["edge_index"][episode, :, edge].tolist()
                g = k % topology.period
                slot = list(topology.neighbour_index[g, i][topology.neighbour_mask[g, i]]).index(j)
                np.testing.assert_array_equal(td["edge_attr"][episode, edge].numpy(), rows[episode, i, slot].ravel())
    # G_{k mod 3}: the graph of instant k is the topology's graph k mod 3.
    for k in range(4):
        edge_index, n_edges = rollout["edge_index"][0, k], int(rollout["n_edges"][0, k])
        np.testing.assert_array_equal(edge_index[:, :n_edges].T.numpy(), env.config.topology.edges[k % 3])
    assert n == env.n_agents


def test_torchrl_env_pads_a_family_to_n_slots_at_every_reset():
    env = torchrl_env(topology=FAMILY, n_agents=6, batch_size=3)
    width = env.config.n_agents * env.config.layout.slots
    for _ in range(3):
        td = env.reset()
        assert td["edge_index"].shape == (3, 2, width) and td["edge_attr"].shape[1] == width
        counts = [len(t.edges[int(g)]) for t, g in zip(env.engine.topologies, env.engine.graph_indices(), strict=True)]
        assert td["n_edges"].tolist() == counts


def test_a_partial_reset_keeps_the_other_episodes_graphs():
    from tensordict import TensorDict
    from torchrl.envs.utils import step_mdp

    from fxc_env import reference_policy

    # Rings dealt to three graphs (some may be empty), a new one per reset of an episode.
    env = torchrl_env(scenario="paper_fig1", topology={"family": "ring", "period": (3, 3)}, batch_size=3)
    module = reference_policy(env)
    td = env.reset()
    for _ in range(2):
        td = step_mdp(env.step(module(td)))
    before = {key: td[key].clone() for key in GRAPH_TENSOR_KEYS}
    kept = env.engine.topologies[1:]
    mask = torch.tensor([[True], [False], [False]])
    # What the environment itself returns for every episode (TorchRL's reset then keeps the
    # others' entries from the tensordict it was given).
    raw = env._reset(TensorDict({"_reset": mask}, batch_size=[3]))
    assert env.engine.topologies[1:] == kept
    for key in GRAPH_TENSOR_KEYS:
        assert torch.equal(raw[key][1:], before[key][1:]), key
    td.set("_reset", mask)
    td = env.reset(td)
    for key in GRAPH_TENSOR_KEYS:
        assert torch.equal(td[key], raw[key]), key
    # The restarted episode plays its new topology's first graph; the others go on to G_{3 mod 3} = G_0.
    restarted = env.engine.topologies[0]
    np.testing.assert_array_equal(td["edge_index"][0, :, : int(td["n_edges"][0])].T.numpy(), restarted.edges[0])
    td = step_mdp(env.step(module(td)))
    for episode in (1, 2):
        count = int(td["n_edges"][episode])
        np.testing.assert_array_equal(td["edge_index"][episode, :, :count].T.numpy(), kept[episode - 1].edges[0])
    np.testing.assert_array_equal(td["edge_index"][0, :, : int(td["n_edges"][0])].T.numpy(), restarted.edges[1])


def test_torchrl_env_without_graph_tensors_has_no_edge_keys():
    from fxc_env import ConsensusTorchEnv

    env = ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, seed=0)
    td = env.reset()
    assert not env.graph_tensors
    assert not any(key in td.keys() or key in env.observation_spec.keys() for key in GRAPH_TENSOR_KEYS)


def test_graph_tensors_must_be_a_bool_named_in_the_error():
    from fxc_env import ConsensusTorchEnv
    from fxc_env.core.validation import ArgumentTypeError

    with pytest.raises(ArgumentTypeError, match="graph_tensors: expected True or False, got 1"):
        ConsensusTorchEnv(scenario="paper_fig1", graph_tensors=1)


# ------------------------------------------------------------------ the PettingZoo environments


def check_info_graph(env, observations, infos, k):
    """Every agent's info holds instant k's graph padded to the env's fixed E, features the observations' rows."""
    topology = env.engine.topologies[0]
    g = k % topology.period
    layout, n, e = env.config.layout, env.config.n_agents, edge_capacity(env.config)
    first = infos["agent_0"]
    count = first["n_edges"]
    assert type(count) is int and count == len(topology.edges[g])
    assert first["edge_index"].shape == (2, e) and first["edge_index"].dtype == np.int64
    assert first["edge_mask"].shape == (e,) and first["edge_mask"].dtype == bool
    assert first["edge_attr"].shape == (e, layout.row_size) and first["edge_attr"].dtype == env.config.observation_dtype
    np.testing.assert_array_equal(first["edge_index"][:, :count].T, topology.edges[g])
    assert (first["edge_index"][:, count:] == n).all() and (first["edge_attr"][count:] == 0).all()
    assert first["edge_mask"].tolist() == [True] * count + [False] * (e - count)
    for agent in env.possible_agents:
        assert all(infos[agent][key] is first[key] for key in GRAPH_TENSOR_KEYS)
    flat = {agent: layout.flat(observation) for agent, observation in observations.items()}
    for (j, i), attr in zip(first["edge_index"][:, :count].T.tolist(), first["edge_attr"], strict=False):
        rows, _, _ = layout.split(flat[f"agent_{i}"])
        slot = list(topology.neighbour_index[g, i][topology.neighbour_mask[g, i]]).index(j)
        np.testing.assert_array_equal(attr, rows[slot].ravel())


@pytest.mark.parametrize(
    "settings",
    [
        {"scenario": "paper_fig1"},
        {"scenario": "paper_fig1", "obs_format": "dict", "obs_dtype": "float32", "dim": 2},
        {"topology": "random", "n_agents": 8, "topology_period": 2, "obs_mode": "raw"},
        {"topology": FAMILY, "n_agents": 6},
    ],
)
@pytest.mark.parametrize("small_n_path", [True, False])
def test_parallel_env_infos_carry_the_current_graph(settings, small_n_path):
    import fxc_env

    env = fxc_env.parallel_env(graph_tensors=True, **settings)
    env.small_n_path = small_n_path
    policy = fxc_env.ReferencePolicy(env)
    observations, infos = env.reset(seed=0)
    check_info_graph(env, observations, infos, 0)
    for k in range(1, 5):
        actions = {agent: policy(observation) for agent, observation in observations.items()}
        observations, _, _, _, infos = env.step(actions)
        check_info_graph(env, observations, infos, k)


def test_parallel_env_without_graph_tensors_keeps_its_infos_numbers_only():
    import fxc_env

    env = fxc_env.parallel_env(scenario="paper_fig1")
    _, infos = env.reset(seed=0)
    assert not env.graph_tensors and all(np.isscalar(value) for value in infos["agent_0"].values())


def test_parallel_env_with_graph_tensors_passes_pettingzoo_s_api_and_seed_tests():
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    import fxc_env

    parallel_api_test(fxc_env.parallel_env(scenario="paper_fig1", graph_tensors=True), num_cycles=5)
    parallel_seed_test(lambda: fxc_env.parallel_env(topology=FAMILY, n_agents=5, graph_tensors=True))


def test_aec_env_infos_carry_the_graph_too():
    import fxc_env

    env = fxc_env.env(scenario="paper_fig1", graph_tensors=True)
    env.reset(seed=0)
    info = env.infos["agent_0"]
    np.testing.assert_array_equal(info["edge_index"][:, : info["n_edges"]].T, env.unwrapped.config.topology.edges[0])


def test_parallel_env_refuses_a_non_bool_graph_tensors_by_name():
    import fxc_env
    from fxc_env.core.validation import ArgumentTypeError

    with pytest.raises(ArgumentTypeError, match="graph_tensors: expected True or False, got 'yes'"):
        fxc_env.parallel_env(scenario="paper_fig1", graph_tensors="yes")


def test_the_readme_s_summing_convolution_equals_the_one_over_the_true_edges():
    from fxc_env import ConsensusTorchEnv

    # docs: graph-tensors.md, "Graph tensors": GraphConv(aggr="add") in plain torch, over N + 1 node rows per episode.
    env = ConsensusTorchEnv(scenario="generalist", batch_size=8, graph_tensors=True, seed=0)
    td = env.reset()
    x = td["agents", "observation"]  # [B, N, obs_size]: the node features
    b, n, f = x.shape
    root, rel = torch.nn.Linear(f, 16, dtype=x.dtype), torch.nn.Linear(f, 16, bias=False, dtype=x.dtype)
    table = torch.cat([x, x.new_zeros(b, 1, f)], dim=1).flatten(0, 1)  # [B (N + 1), F]
    offset = (n + 1) * torch.arange(b)[:, None, None]
    source, target = (td["edge_index"] + offset).unbind(1)  # [B, E] each
    summed = torch.zeros_like(table).index_add_(0, target.flatten(), table[source.flatten()])
    out = root(x) + rel(summed.reshape(b, n + 1, f)[:, :n])  # [B, N, 16]
    # The same convolution over each episode's true edges only (its first n_edges).
    assert (td["n_edges"] < td["edge_index"].shape[-1]).all()  # every episode has padding
    for episode in range(b):
        count = int(td["n_edges"][episode])
        j, i = td["edge_index"][episode, :, :count]
        true_sum = torch.zeros(n, f, dtype=x.dtype).index_add_(0, i, x[episode, j])
        torch.testing.assert_close(out[episode], root(x[episode]) + rel(true_sum), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    "settings", [{"topology": FAMILY, "n_agents": 7}, {"topology": "complete", "n_agents": 6, "link_dropout": 0.4}]
)
def test_a_sum_over_the_padded_edges_equals_the_sum_over_the_true_edges(settings):
    engine = started(make_config(**settings), b=5, seed=2)
    edge_index, _, n_edges, edge_attr = host(graph_tensors(engine, width=edge_capacity(engine.config)))
    n = engine.config.n_agents
    assert (n_edges < edge_index.shape[-1]).all()  # padded everywhere
    x = np.random.default_rng(0).normal(size=(5, n + 1, 3))
    for b in range(5):
        # A scatter-add over every column, padding included, into N + 1 rows: row N takes the padding.
        padded = np.zeros((n + 1, 3))
        np.add.at(padded, edge_index[b, 1], x[b, edge_index[b, 0]] + edge_attr[b, :, :1])  # zero features on padding
        true = np.zeros((n, 3))
        j, i = edge_index[b, :, : n_edges[b]]
        np.add.at(true, i, x[b, j] + edge_attr[b, : n_edges[b], :1])
        np.testing.assert_array_equal(padded[:n], true)
        # On a node table of N rows a padded edge is out of range: it raises, it never adds to agent 0.
        with pytest.raises(IndexError):
            np.add.at(np.zeros((n, 3)), edge_index[b, 1], x[b, :n][edge_index[b, 0]])
