"""The filtering law: dead-beat factors on free-motion predictions, each read by least squares over a block."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import recorded_observations, stream_actions

from fxc_env.baselines import FilteringPolicy
from fxc_env.baselines.harness.filtering_goals import goal_table
from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import BenchmarkCase, builtin_contenders, load_policy, optimality_contenders
from fxc_env.baselines.registry import LAWS
from fxc_env.config import make_config
from fxc_env.core.families import TopologyFamily
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine

SETTINGS = {"schedule": "uniform", "action_mode": "plan", "obs_mode": "raw"}
RANDOM_8 = {"topology": "random", "n_agents": 8, "topology_seed": 1}


def episodes(policy_kwargs=None, seeds=(0, 1, 2), **kwargs):
    """Run the law on seeded episodes; the policy and its batch metrics."""
    config = make_config(**{**SETTINGS, **kwargs})
    policy = FilteringPolicy(config, **(policy_kwargs or {}))
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in seeds]
    engine.reset_from_draws(draws, rng=np.random.default_rng([*seeds, 7]))  # seeded noise: a repeatable test
    while not engine.done:
        engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    return policy, engine.batch_metrics()


@pytest.mark.parametrize("graph", [{"topology": "ring", "n_agents": 6}, RANDOM_8], ids=["ring", "random"])
@pytest.mark.parametrize("action_mode", ["plan", "accel"])
def test_without_noise_it_is_exact_after_its_factors(graph, action_mode):
    policy, metrics = episodes(n_intervals=100, action_mode=action_mode, **graph)
    assert np.max(metrics["relative_deadline_error"]) <= 1e-9
    assert policy.parameters()["blocks"] * policy.block + policy.spread <= 100


def test_under_noise_a_longer_block_averages_the_noise_down():
    # Ring of 20, sigma = 1e-3: each factor reads the least-squares mean of block - spread + 1 rows.
    kwargs = {"topology": "ring", "n_agents": 20, "n_intervals": 200, "obs_noise": 1e-3}
    _, short = episodes({"block": 5, "damping": 0}, seeds=tuple(range(8)), **kwargs)
    _, long = episodes({"damping": 0}, seeds=tuple(range(8)), **kwargs)  # block 10: 7 rows per factor (block 5: 2)
    assert np.median(long["relative_deadline_error"]) < 0.6 * np.median(short["relative_deadline_error"])


def test_the_damping_blocks_average_down_what_the_factors_noise_left():
    graph = {"topology": "random", "n_agents": 20, "mean_in_degree": 2.0, "topology_seed": 0}
    kwargs = {**graph, "n_intervals": 200, "obs_noise": 1e-3}
    _, plain = episodes({"damping": 0}, seeds=tuple(range(8)), **kwargs)
    _, damped = episodes(seeds=tuple(range(8)), **kwargs)
    assert np.median(damped["relative_deadline_error"]) < 0.7 * np.median(plain["relative_deadline_error"])


def test_the_goal_figures_at_sigma_1e_3():
    # docs: optimality.md, "Filtered dead-beat (`filtering`)": medians over 20 seeds, uniform K = 200.
    lines = dict(line.split(": ") for line in goal_table().splitlines()[1:])
    for case, (error_bound, energy_bound) in {"ring": (1e-3, 2e8), "random": (2.5e-4, 1e6)}.items():
        error, floor, ratio, energy = (float(v) for v in lines[case].split(", "))
        assert floor < error <= error_bound and ratio > 1.0  # above the floor no law beats
        assert energy <= energy_bound


def test_agent_i_acts_on_its_own_rows_only_and_the_graph_relabelled_changes_nothing():
    config = make_config(**SETTINGS, topology="ring", n_agents=6, n_intervals=100, obs_noise=1e-3)
    stream = recorded_observations(FilteringPolicy, config)
    reference = stream_actions(FilteringPolicy(config), stream)
    rng = np.random.default_rng(3)
    rows_part = slice(0, config.layout.size - 3)
    for i in range(config.n_agents):
        scrambled = stream.copy()
        others = np.arange(config.n_agents) != i
        scrambled[:, others, rows_part] = rng.normal(size=scrambled[:, others, rows_part].shape)
        changed = stream_actions(FilteringPolicy(config), scrambled)
        np.testing.assert_array_equal(changed[:, i], reference[:, i])
        assert not np.allclose(changed[:, others], reference[:, others])
    # Built on the same ring with its agents relabelled (a permutation), it acts alike on the same stream.
    order = np.random.default_rng(0).permutation(6)
    edges = [(int(order[j]), int(order[(j + 1) % 6])) for j in range(6)]
    relabelled = make_config(**SETTINGS, topology=edges, n_agents=6, n_intervals=100, obs_noise=1e-3)
    np.testing.assert_array_equal(stream_actions(FilteringPolicy(relabelled), stream), reference)


@pytest.mark.parametrize(
    ("kwargs", "policy_kwargs", "name"),
    [
        ({"topology": "paper_fig1", "n_agents": 6}, {}, "topology"),
        ({"topology": TopologyFamily("ring")}, {}, "topology"),
        ({"topology": [[(0, 1)], [(1, 2)], [(2, 0)]], "n_agents": 3, "switching": "random"}, {}, "topology"),
        ({"u_max": 10.0}, {}, "u_max"),
        ({"link_dropout": 0.1}, {}, "link_dropout"),
        ({"agent_model": "single_integrator"}, {}, "agent_model"),
        ({"obs_mode": "normalized"}, {}, "obs_mode"),
        ({"action_mode": "residual"}, {}, "action_mode"),
        ({"n_intervals": 10}, {}, "n_intervals"),  # 5 blocks of at least 2 intervals, then a move of 1
        ({}, {"block": 8}, "block"),  # at most (100 - 4) // 13 = 7
        ({}, {"block": 4}, "block"),  # at least spread + 1
        ({}, {"spread": 0}, "spread"),
        ({}, {"damping": -1}, "damping"),
    ],
)
def test_it_refuses_by_name_what_it_cannot_honour(kwargs, policy_kwargs, name):
    settings = {**SETTINGS, "topology": "ring", "n_agents": 6, "n_intervals": 100, "obs_noise": 1e-3, **kwargs}
    with pytest.raises(ArgumentError, match=rf"^{name}:"):
        FilteringPolicy(make_config(**settings), **policy_kwargs)
    fitting = FilteringPolicy(make_config(**SETTINGS, topology="ring", n_agents=6, n_intervals=11, obs_noise=1e-3))
    assert (fitting.block, fitting.spread, fitting.damping) == (2, 1, 0)  # the defaults shrink to fit a short K


def test_its_memory_needs_every_agent_at_once_from_the_first_instant():
    config = make_config(**SETTINGS, topology="ring", n_agents=6, n_intervals=100, obs_noise=1e-3)
    policy = FilteringPolicy(config)
    engine = ConsensusEngine(config, n_episodes=1)
    engine.reset(np.arange(6.0)[None, :, None], np.zeros((1, 6, 1)))
    obs = engine.observations()
    with pytest.raises(
        ArgumentError, match=r"^observations: FilteringPolicy \(filtering\) acts for every agent at once"
    ):
        policy(obs[0, 0])
    engine.step(policy(obs))
    with pytest.raises(ArgumentError, match=r"^observation:"):
        FilteringPolicy(config)(engine.observations())


def test_the_registry_and_the_benchmark_run_it_under_noise_without_an_opt_in():
    law = LAWS["filtering"]
    assert law.policy is FilteringPolicy and not law.opt_ins and not law.leaderboard
    config = make_config(**SETTINGS, topology="ring", n_agents=6, obs_noise=1e-3)
    assert isinstance(load_policy("filtering", config), FilteringPolicy)
    assert "filtering" in {c.name for c in optimality_contenders()}
    job = Job(builtin_contenders(["filtering"])[0], BenchmarkCase("ring", 6), 100, (0,), 20.0, False)
    result = run_job(job)
    assert result.error is None and result.description["name"] == "filtering"
    assert result.metrics["relative_deadline_error"][0] <= 1e-9
