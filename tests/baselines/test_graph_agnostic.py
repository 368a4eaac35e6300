"""The graph-agnostic law: exact consensus from own rows only, given nothing but an upper bound on N."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import recorded_observations, stream_actions

from fxc_env.baselines import GraphAgnosticPolicy
from fxc_env.baselines.harness.graph_agnostic_goals import strongly_connected_random
from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import BenchmarkCase, builtin_contenders, load_policy, optimality_contenders
from fxc_env.baselines.laws.graph_agnostic import listening_values, recurrence_limit
from fxc_env.config import make_config
from fxc_env.core.families import TopologyFamily
from fxc_env.core.optimality import energy_bound
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine

SETTINGS = {"scenario": None, "schedule": "uniform", "action_mode": "plan", "obs_mode": "raw"}
# A strongly connected random digraph (topology_seed 1 of N = 8 at mean in-degree 2): its consensus
# weights ξ are not uniform, so the law agrees on ξᵀ p, not on the mean prediction.
RANDOM_8 = {"topology": "random", "n_agents": 8, "topology_seed": 1}


def episodes(policy_kwargs=None, seeds=(0, 1, 2), **kwargs):
    """Run the law on seeded episodes; the policy, the engine (for z0) and its batch metrics."""
    config = make_config(**{**SETTINGS, **kwargs})
    policy = GraphAgnosticPolicy(config, **(policy_kwargs or {}))
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in seeds]
    engine.reset(np.stack([d.x0 for d in draws]), np.stack([d.v0 for d in draws]))
    while not engine.done:
        engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    return policy, engine, engine.batch_metrics()


@pytest.mark.parametrize("graph", [{"topology": "ring", "n_agents": 6}, RANDOM_8], ids=["ring", "random"])
@pytest.mark.parametrize("factor", [1, 2], ids=["max_agents=N", "max_agents=2N"])
def test_it_reaches_exact_consensus_without_the_graph_on_a_small_ring_and_a_random_digraph(graph, factor):
    policy, _, metrics = episodes({"max_agents": factor * graph["n_agents"]}, n_intervals=60, **graph)
    assert np.max(metrics["relative_deadline_error"]) <= 1e-8
    assert np.all(metrics["energy_ratio"] >= 1.0)  # E* bounds every exact consensus
    # The window: about 1.5 max_agents values with both register parts as channels (2 max_agents + 2 with one).
    assert policy.listening == listening_values(factor * graph["n_agents"], 2) < policy.full_listening
    assert policy.full_listening == 2 * factor * graph["n_agents"] + 2
    # The rank test found the degree of the minimal polynomial seen from each agent, at most N - 1.
    assert np.all(policy.degrees <= graph["n_agents"] - 1)


def test_on_a_ring_it_steers_once_to_the_mean_prediction_after_its_window():
    policy, engine, metrics = episodes(topology="ring", n_agents=6, dim=2, n_intervals=60)
    x0, v0 = engine.z0[:, :, 0], engine.z0[:, :, 1]  # (B, N, dim)
    mean_prediction = (x0 + 20.0 * v0).mean(axis=1)
    assert np.max(np.abs(engine.x - mean_prediction[:, None, :])) <= 1e-8
    t_l = policy.parameters()["steer_start_s"]
    assert policy.listening == 6 + 2 + 1  # four channels (two axes, position and velocity): 6 + ceil(7 / 4) + 1
    # One interval is held for the pre-steer announcement; on a ring the iterate never settles: no pre-steer.
    assert policy.announce_at == 5 and t_l == pytest.approx((policy.listening - 1) * 20.0 / 60)
    steer = energy_bound(x0 + t_l * v0, v0, 20.0 - t_l)  # the least energy of one steer from t_L
    assert np.all(metrics["energy"] >= steer)
    np.testing.assert_allclose(metrics["energy"], steer, rtol=1e-2)  # plus the signalling, ~ε²
    # A directed ring of N: every agent's recurrence is λ^N - 1, so p has degree N - 1.
    assert np.all(policy.degrees == 5)


@pytest.mark.parametrize("velocity", ["zero", "affine"])
def test_when_the_register_parts_are_dependent_every_agent_listens_on_to_the_one_channel_window(velocity):
    # Every velocity equal (or an affine function of the position): the velocity part of the register adds no
    # information, every agent sees it alike and listens 2 max_agents intervals before it steers: still exact.
    config = make_config(**SETTINGS, topology="ring", n_agents=8, n_intervals=60)
    policy = GraphAgnosticPolicy(config)
    engine = ConsensusEngine(config, n_episodes=3)
    x0 = np.random.default_rng(0).normal(size=(3, 8, 1))
    v0 = np.full_like(x0, 0.3) if velocity == "zero" else 0.5 * x0 - 1.0
    engine.reset(x0, v0)
    while not engine.done:
        engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    metrics = engine.batch_metrics()
    assert np.max(metrics["relative_deadline_error"]) <= 1e-8
    t_full = (policy.full_listening - 1) * 20.0 / 60  # one interval held for the pre-steer announcement
    steer = energy_bound(x0 + t_full * v0, v0, 20.0 - t_full)
    assert np.all(metrics["energy"] >= steer)  # nobody steered before the one-channel window


def test_each_agent_reads_the_limit_of_the_iteration_off_its_own_shortest_recurrence():
    # Yuan et al. 2013 on the bare iteration w <- D^-1 A w of a random strongly connected digraph: every agent's
    # own values (two channels, 1.5 N + 1 of them) give xi^T w(0), xi the left Perron vector, and the degree of
    # the minimal polynomial it sees (at most N - 1 for the differences).
    config = make_config(**SETTINGS, **RANDOM_8)
    adjacency = config.topology.adjacency(0).toarray()
    W = adjacency / adjacency.sum(axis=1, keepdims=True)
    values, vectors = np.linalg.eig(W.T)
    xi = np.real(vectors[:, np.argmin(np.abs(values - 1.0))])
    xi /= xi.sum()
    w = np.random.default_rng(0).normal(size=(8, 2))  # two channels
    L = listening_values(8, 2)
    sequence = [w]
    for _ in range(L - 1):
        sequence.append(W @ sequence[-1])
    recorded = np.stack(sequence, axis=-1)  # (N agents, 2 channels, L values)
    limits, degrees, certified = recurrence_limit(recorded, 7, 1e-10)
    np.testing.assert_allclose(limits, np.broadcast_to(xi @ w, (8, 2)), atol=1e-10)
    assert np.all(degrees <= 7) and np.all(certified)
    assert not np.allclose(xi, 1 / 8)  # a weighted limit, not the mean


def test_agent_i_acts_on_its_own_rows_only_and_never_on_the_graph():
    config = make_config(**SETTINGS, **RANDOM_8, n_intervals=60)
    stream = recorded_observations(GraphAgnosticPolicy, config)
    reference = stream_actions(GraphAgnosticPolicy(config), stream)
    rng = np.random.default_rng(3)
    layout = config.layout
    for i in range(config.n_agents):
        scrambled = stream.copy()
        others = np.arange(config.n_agents) != i
        # Every other agent's rows (relative states and mask) replaced by noise; the clock kept (shared).
        rows_part = slice(0, layout.size - 3)
        scrambled[:, others, rows_part] = rng.normal(size=scrambled[:, others, rows_part].shape)
        changed = stream_actions(GraphAgnosticPolicy(config), scrambled)
        np.testing.assert_array_equal(changed[:, i], reference[:, i])
        assert not np.allclose(changed[:, others], reference[:, others])
    # The graph it is built with never enters its actions: built on another digraph with the same
    # observation layout (a directed ring of the same N, in-degree padded to the same slots), same actions.
    other = make_config(**SETTINGS, topology="ring", n_agents=8, n_intervals=60, obs_slots=layout.slots)
    assert other.layout.size == layout.size
    np.testing.assert_array_equal(stream_actions(GraphAgnosticPolicy(other), stream), reference)


@pytest.mark.parametrize(
    ("kwargs", "policy_kwargs", "name"),
    [
        ({"u_max": 10.0}, {}, "u_max"),
        ({"obs_noise": 1e-6}, {}, "obs_noise"),
        ({"link_dropout": 0.1}, {}, "link_dropout"),
        ({"scenario": "paper_fig1", "topology": None, "n_agents": None}, {}, "topology"),
        ({"topology": [[(0, 1)], [(1, 2)], [(2, 0)]], "n_agents": 3, "switching": "random"}, {}, "topology"),
        ({"topology": TopologyFamily("ring")}, {}, "topology"),
        ({"agent_model": "single_integrator"}, {}, "agent_model"),
        ({"obs_mode": "normalized"}, {}, "obs_mode"),
        ({"n_intervals": 12}, {}, "n_intervals"),  # the window of N = 6 is 12 intervals, then one to steer
        ({}, {"max_agents": 5}, "max_agents"),
        ({}, {"amplitude": 0.0}, "amplitude"),
        ({}, {"rank_tolerance": 1.0}, "rank_tolerance"),
    ],
)
def test_it_refuses_by_name_what_it_cannot_honour(kwargs, policy_kwargs, name):
    settings = {**SETTINGS, "topology": "ring", "n_agents": 6, **kwargs}
    settings = {k: v for k, v in settings.items() if v is not None}
    with pytest.raises(ArgumentError, match=rf"^{name}:"):
        GraphAgnosticPolicy(make_config(**settings), **policy_kwargs)
    fitting = GraphAgnosticPolicy(make_config(**SETTINGS, topology="ring", n_agents=6, n_intervals=13))
    assert fitting.full_listening == listening_values(6) == 14


def test_its_memory_needs_every_agent_at_once_from_the_first_instant():
    config = make_config(**SETTINGS, topology="ring", n_agents=6)
    policy = GraphAgnosticPolicy(config)
    engine = ConsensusEngine(config, n_episodes=1)
    engine.reset(np.arange(6.0)[None, :, None], np.zeros((1, 6, 1)))
    obs = engine.observations()
    with pytest.raises(
        ArgumentError, match=r"^observations: GraphAgnosticPolicy \(graph_agnostic\) acts for every agent at once"
    ):
        policy(obs[0, 0])  # one agent alone
    engine.step(policy(obs))
    with pytest.raises(ArgumentError, match=r"^observation:"):
        GraphAgnosticPolicy(config)(engine.observations())  # k = 1 without its k = 0


def test_accel_actions_spend_what_plans_spend():
    _, _, plan = episodes(topology="ring", n_agents=6, n_intervals=60)
    _, _, accel = episodes(topology="ring", n_agents=6, n_intervals=60, action_mode="accel")
    np.testing.assert_allclose(accel["energy"], plan["energy"], rtol=1e-9)


def test_the_benchmark_and_evaluate_run_it():
    config = make_config(**SETTINGS, topology="ring", n_agents=6)
    assert isinstance(load_policy("graph_agnostic", config), GraphAgnosticPolicy)
    assert "graph_agnostic" in [c.name for c in builtin_contenders()]
    assert {"graph_agnostic", "graph_agnostic/paper"} <= {c.name for c in optimality_contenders()}
    job = Job(builtin_contenders(["graph_agnostic"])[0], BenchmarkCase("ring", 6), 60, (0,), 20.0, False)
    result = run_job(job)
    assert result.error is None and result.description["name"] == "graph_agnostic"
    assert result.metrics["relative_deadline_error"][0] <= 1e-8


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "n_agents", "error", "energy"),
    [("ring", 20, 1e-9, 2.5), ("ring", 30, 1e-9, 3.5), ("random", 20, 1e-7, 3.0), ("random", 40, 1e-7, 3.0)],
    ids=["ring-20", "ring-30", "random-20", "random-40"],
)
def test_the_goals_at_k_200(case, n_agents, error, energy):
    # docs: optimality.md, "Exact consensus without knowing the graph": uniform K = 200, T_s = 20, max_agents = N; the random
    # digraphs at mean in-degree 2 (N = 20) and 3 (N = 40). N = 40 needs the pre-steer (one steer from t_L = 6 s
    # alone costs 4.0 x E*).
    topology = "ring" if case == "ring" else strongly_connected_random(n_agents, n_agents / 20 + 1)[0]
    _, _, metrics = episodes(seeds=(0, 1, 2, 3), topology=topology, n_agents=n_agents, n_intervals=200)
    assert np.median(metrics["relative_deadline_error"]) <= error
    assert np.median(metrics["energy_ratio"]) <= energy


def test_on_a_random_digraph_it_pre_steers_toward_its_settled_iterate_and_spends_less_than_one_late_steer():
    # The announcement: each agent's aim a_i (its iterate, weighted by how settled it looks, on a grid relative to its loudness)
    # is read by its out-neighbours exactly, so its later pre-steer motion is known to them and the iteration's
    # numbers still come through. The steer from t_L then has little left to do.
    settings = {"topology": strongly_connected_random(20, 2.0)[0], "n_intervals": 200}
    policy, engine, metrics = episodes(seeds=(0, 1), **settings)
    assert np.max(metrics["relative_deadline_error"]) <= 1e-7
    t_l = policy.parameters()["steer_start_s"]
    assert policy.announce_at == 10 and t_l == pytest.approx(3.1)
    x0, v0 = engine.z0[:, :, 0], engine.z0[:, :, 1]
    # Less than the least energy of one steer from t_L to the very same point (where the agents ended): per agent
    # 12 a²/H³ - 12 a b/H² + 4 b²/H, a and b the position (at T_s) and velocity changes, H = T_s - t_L.
    a, b, H = engine.x[:, :1] - (x0 + 20.0 * v0), engine.v[:, :1] - v0, 20.0 - t_l
    late = np.sum(12 * a**2 / H**3 - 12 * a * b / H**2 + 4 * b**2 / H, axis=(1, 2))
    assert np.all(metrics["energy"] < 0.7 * late)
    assert np.all(metrics["energy_ratio"] <= 2.0)
    # Without the announcement (announce_at = 0) the same law steers once from t_L = 3.0 s: exact, costlier.
    plain, _, without = episodes({"announce_at": 0}, seeds=(0, 1), **settings)
    assert plain.announce_at is None and plain.parameters()["steer_start_s"] == pytest.approx(3.0)
    assert np.max(without["relative_deadline_error"]) <= 1e-7
    assert np.all(without["energy"] > metrics["energy"])


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3, 1e6])
def test_the_announced_aims_are_read_back_exactly_in_any_units(scale):
    from fxc_env.baselines.laws.graph_agnostic import AIM_BITS, ANNOUNCE, heard_aim, presteer_aim
    from fxc_env.baselines.laws.signalling import deviation_of

    rng = np.random.default_rng(0)
    values = scale * (rng.normal(size=(6, 3, 1)) + 1j * rng.normal(size=(6, 3, 1)))
    values[:2] = values[:2, -1:] + 1e-6 * values[:2]  # two settled iterates, three wandering
    values[5] = 0  # an agent with no in-neighbour never moves: silent
    aims = presteer_aim(values)
    assert np.all(aims[2:] == 0) and np.all(aims[:2] != 0)
    # On a power-of-two grid relative to the sender's loudness |c(k_a)|, not in metres.
    grid = 2.0 ** (np.ceil(np.log2(np.abs(values[:2, 1, 0]))) - AIM_BITS + 1)
    assert np.all(np.mod(aims[:2, 0].real, grid) == 0) and np.all(np.mod(aims[:2, 0].imag, grid) == 0)
    heard = values[:, 1] + scale * 1e-9 * rng.normal(size=(6, 1))  # c_j(k_a) as read at k_a: off by rounding
    deviation = deviation_of(aims, ANNOUNCE, 20.0) + deviation_of(heard, 3e-6, 20.0)
    deviation = deviation + scale * 1e-15 * rng.normal(size=deviation.shape)  # rounding of measured rows
    spread = np.array(5.0 * scale)  # one reader of all six: its register spread max_j |w_j(0) - w_i(0)|
    np.testing.assert_array_equal(heard_aim(deviation, heard, spread, 3e-6, 20.0), aims)


def single_root_dag(n_agents: int, extra: int, seed: int) -> list[tuple[int, int]]:
    """A random tree from one root plus ``extra`` edges (j, i) from earlier to later agents: no cycle at all."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(n_agents)
    edges = {(int(order[rng.integers(0, k)]), int(order[k])) for k in range(1, n_agents)}
    while len(edges) < n_agents - 1 + extra:
        a, b = sorted(int(x) for x in rng.choice(np.arange(1, n_agents), size=2, replace=False))
        edges.add((int(order[a]), int(order[b])))
    return sorted(edges)


@pytest.mark.parametrize("n_agents", [30, 40])
def test_exact_on_single_root_digraphs_whose_rest_is_acyclic_in_any_units(n_agents):
    # A directed spanning tree, not strongly connected: the root has no in-neighbour and never moves (its readers
    # hear rounding only and read its aim as 0); the rest is acyclic, so its modes vanish after finitely many steps.
    edges = single_root_dag(n_agents, n_agents, 200)
    for scale in (1.0, 1e3):
        config = make_config(**SETTINGS, topology=edges, n_agents=n_agents, n_intervals=200)
        policy = GraphAgnosticPolicy(config)
        engine = ConsensusEngine(config, n_episodes=3)
        draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in range(3)]
        engine.reset(scale * np.stack([d.x0 for d in draws]), scale * np.stack([d.v0 for d in draws]))
        while not engine.done:
            engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
        assert np.max(engine.batch_metrics()["relative_deadline_error"]) <= 1e-9


def test_it_refuses_by_name_a_graph_with_a_cycle_outside_its_root_set():
    # A single root, and a cycle among the others (3 -> 4 -> 5 -> 3, fed from the root's tree): its leaky block's
    # slowly decaying modes are what the rank test cannot tell from reading errors.
    edges = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 3), (1, 6), (6, 7)]
    with pytest.raises(ArgumentError, match=r"^topology: .*agents \[3, 4, 5\] lie on a cycle outside"):
        GraphAgnosticPolicy(make_config(**SETTINGS, topology=edges, n_agents=8, n_intervals=60))
    # The same graph without the cycle's closing edge (a path with branches) is in its class.
    GraphAgnosticPolicy(make_config(**SETTINGS, topology=edges[:5] + edges[6:], n_agents=8, n_intervals=60))


@pytest.mark.parametrize("value", [1, 8, True])
def test_it_refuses_an_announcement_outside_its_window_by_name(value):
    config = make_config(**SETTINGS, topology="ring", n_agents=6, n_intervals=60)  # 11 values: instants 2..7
    with pytest.raises(ArgumentError, match=r"^announce_at:"):
        GraphAgnosticPolicy(config, announce_at=value)
