"""The signalling law: a few x E* at a deadline error far below 1e-6, energy never below E*, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env.baselines import SignallingPolicy
from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import (
    BenchmarkCase,
    Contender,
    builtin_contenders,
    load_policy,
    optimality_contenders,
)
from fxc_env.config import make_config
from fxc_env.core.families import TopologyFamily
from fxc_env.core.optimality import energy_bound
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine

SIGNALLING = Contender("signalling", "signalling", True, "uniform", "plan", "raw")


def episodes(seeds=(0, 1, 2), amplitude=None, **kwargs):
    """Run the law on seeded episodes; the engine (for z0) and its batch metrics."""
    kwargs = {"scenario": None, "schedule": "uniform", "action_mode": "plan", "obs_mode": "raw", **kwargs}
    config = make_config(**kwargs)
    policy = SignallingPolicy(config, amplitude=amplitude)
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in seeds]
    engine.reset(np.stack([d.x0 for d in draws]), np.stack([d.v0 for d in draws]))
    while not engine.done:
        engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    return policy, engine, engine.batch_metrics()


@pytest.mark.parametrize(
    "case", [BenchmarkCase("ring", 6), BenchmarkCase("random", 8), BenchmarkCase("paper_fig1", 6)], ids=str
)
def test_the_deadline_error_is_below_1e_6_at_under_3_times_the_energy_bound(case):
    result = run_job(Job(SIGNALLING, case, 200, tuple(range(5)), 20.0, False))
    assert result.error is None
    metrics = result.metrics
    assert np.max(metrics["relative_deadline_error"]) <= 1e-6
    assert np.all(metrics["energy_ratio"] >= 1.0)  # E* bounds every exact consensus
    assert np.max(metrics["energy_ratio"]) <= 3.0


def test_on_a_strongly_connected_ring_it_reaches_the_mean_prediction_with_one_minimum_energy_steer():
    policy, engine, metrics = episodes(topology="ring", n_agents=6, dim=2)
    x0, v0 = engine.z0[:, :, 0], engine.z0[:, :, 1]  # (B, N, dim)
    mean_prediction = (x0 + 20.0 * v0).mean(axis=1)
    assert np.max(np.abs(engine.x - mean_prediction[:, None, :])) <= 1e-8  # every agent at the mean prediction
    # The energy is the least energy of a steer over T_s - t_c from the coasted state, plus the signalling
    # (about 1e-4 of it at ε = 1e-6 and T = 0.1 s).
    t_c = policy.parameters()["steer_start_s"]
    steer = energy_bound(x0 + t_c * v0, v0, 20.0 - t_c)
    assert np.all(metrics["energy"] >= steer)
    np.testing.assert_allclose(metrics["energy"], steer, rtol=1e-3)
    assert np.all(metrics["energy"] >= energy_bound(x0, v0, 20.0))


def test_the_ring_agrees_in_n_minus_1_intervals_and_a_random_digraph_needs_a_second_stage():
    ring = SignallingPolicy(make_config(scenario=None, topology="ring", n_agents=6, obs_mode="raw"))
    assert ring.agreement_intervals == 5 and not ring.two_stages  # the propagation bound of a directed ring
    fig1 = SignallingPolicy(make_config(scenario="paper_fig1", obs_mode="raw"))
    assert fig1.agreement_intervals == 15  # 3 graphs per period x 5 updates on the union ring
    random = SignallingPolicy(make_config(scenario=None, topology="random", n_agents=8, obs_mode="raw"))
    assert random.two_stages and random.agreement_intervals == 14


def test_accel_actions_spend_what_plans_spend():
    _, _, plan = episodes(topology="ring", n_agents=6)
    _, _, accel = episodes(topology="ring", n_agents=6, action_mode="accel")
    np.testing.assert_allclose(accel["energy"], plan["energy"], rtol=1e-9)


def test_the_amplitude_trades_signalling_energy_for_reading_precision():
    _, _, small = episodes(topology="random", n_agents=8)
    config = make_config(scenario=None, topology="random", n_agents=8, schedule="uniform", obs_mode="raw")
    loud = SignallingPolicy(config, amplitude=1e-2)
    engine = ConsensusEngine(config, n_episodes=3)
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in (0, 1, 2)]
    engine.reset(np.stack([d.x0 for d in draws]), np.stack([d.v0 for d in draws]))
    while not engine.done:
        engine.step(np.asarray(loud(engine.observations()), dtype=np.float64))
    assert np.all(engine.batch_metrics()["energy"] > small["energy"])


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"u_max": 10.0}, "u_max"),
        ({"link_dropout": 0.1}, "link_dropout"),
        ({"topology": [[(0, 1)], [(1, 2)], [(2, 0)]], "n_agents": 3, "switching": "random"}, "switching"),
        ({"obs_noise": 1e-6}, "obs_noise"),
        ({"topology": TopologyFamily("ring")}, "topology"),
        ({"agent_model": "single_integrator"}, "agent_model"),
        ({"obs_mode": "normalized"}, "obs_mode"),
        ({"n_intervals": 4}, "n_intervals"),
    ],
)
def test_it_refuses_by_name_what_it_cannot_honour(kwargs, name):
    settings = {"scenario": None, "topology": "ring", "n_agents": 6, "obs_mode": "raw", **kwargs}
    config = make_config(**settings)
    with pytest.raises(ArgumentError, match=rf"^{name}:"):
        SignallingPolicy(config)
    with pytest.raises(ArgumentError, match=r"^amplitude:"):
        SignallingPolicy(make_config(scenario=None, topology="ring", n_agents=6, obs_mode="raw"), amplitude=0.0)


@pytest.mark.parametrize(("inside", "outside"), [(1e-12, 1e-13), (1.0, 1.5)])
def test_it_refuses_amplitudes_past_where_the_reads_decode_and_the_ends_of_the_range_still_decode(inside, outside):
    """Below 1e-12 rounding over ε takes the reads' digits; above 1 the error grows again like ε (docs: optimality.md)."""
    config = make_config(scenario=None, topology="ring", n_agents=6, obs_mode="raw")
    for bad in (outside, 1e-16, 1e12, 1e300):
        with pytest.raises(ArgumentError, match=r"^amplitude: expected 1e-12 <= amplitude <= 1; .*got "):
            SignallingPolicy(config, amplitude=bad)
    _, _, metrics = episodes(topology="ring", n_agents=6, amplitude=inside)
    assert np.max(metrics["relative_deadline_error"]) < 1e-3


def test_under_measurement_noise_it_runs_only_with_a_chosen_amplitude_and_loses_accuracy_like_one_over_it():
    config = make_config(scenario=None, topology="ring", n_agents=6, obs_mode="raw", schedule="uniform", obs_noise=1e-6)
    errors = []
    for amplitude in (1e-4, 1e-2):
        policy = SignallingPolicy(config, amplitude=amplitude)
        engine = ConsensusEngine(config, n_episodes=5)
        draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in range(5)]
        engine.reset(np.stack([d.x0 for d in draws]), np.stack([d.v0 for d in draws]), rng=np.random.default_rng(7))
        while not engine.done:
            engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
        errors.append(np.median(engine.batch_metrics()["relative_deadline_error"]))
    assert errors[1] < errors[0] / 10  # 100 x the amplitude: reading errors 100 x smaller


def test_its_memory_needs_every_agent_at_once_from_the_first_instant():
    config = make_config(scenario=None, topology="ring", n_agents=6, obs_mode="raw")
    policy = SignallingPolicy(config)
    engine = ConsensusEngine(config, n_episodes=1)
    engine.reset(np.arange(6.0)[None, :, None], np.zeros((1, 6, 1)))
    obs = engine.observations()
    with pytest.raises(
        ArgumentError, match=r"^observations: SignallingPolicy \(signalling\) acts for every agent at once"
    ):
        policy(obs[0, 0])  # one agent alone
    engine.step(policy(obs))
    with pytest.raises(ArgumentError, match=r"^observation:"):
        SignallingPolicy(config)(engine.observations())  # k = 1 without its k = 0: no memory of the start


def test_the_benchmark_and_evaluate_run_it():
    config = make_config(scenario="paper_fig1", obs_mode="raw", schedule="uniform")
    assert isinstance(load_policy("signalling", config), SignallingPolicy)
    assert "signalling" in [c.name for c in builtin_contenders()]
    assert {"signalling", "signalling/paper"} <= {c.name for c in optimality_contenders()}
    result = run_job(Job(builtin_contenders(["signalling"])[0], BenchmarkCase("paper_fig1", 6), 200, (0,), 20.0, False))
    assert result.error is None and result.description["name"] == "signalling"
    assert result.guarantee.startswith("agreement after 15 intervals")
