"""Sampled-data linear consensus (Cao & Ren 2010): gains designed for h = T_s / K, exact ZOH steps."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ConsensusEngine, make_config
from fxc_env.baselines.laws import design
from fxc_env.baselines.laws.sampled import SampledLinearPolicy


def config_for(topology="ring", n_agents=6, n_intervals=25, settling_time=20.0, **kwargs):
    return make_config(
        topology=topology,
        n_agents=n_agents,
        n_intervals=n_intervals,
        settling_time=settling_time,
        schedule="uniform",
        action_mode="accel",
        obs_mode="raw",
        **kwargs,
    )


def test_one_sample_is_the_hand_computed_zero_order_hold_step():
    config = config_for(topology=[(1, 0), (2, 0), (0, 1), (0, 2)], n_agents=3, n_intervals=10)
    policy = SampledLinearPolicy(config, gamma=2.0, gain=0.5)
    x0, v0 = np.array([0.0, 1.0, -3.0]), np.array([0.0, 0.5, 2.0])
    engine = ConsensusEngine(config)
    engine.reset(x0[None, :, None], v0[None, :, None])
    engine.step(policy(engine.observations()))
    # u = -g sum_j [(x_i - x_j) + gamma (v_i - v_j)] = [1.5, -1, -0.5]; h = 2 s, held constant.
    u, h = np.array([1.5, -1.0, -0.5]), 2.0
    np.testing.assert_allclose(engine.x[0, :, 0], x0 + h * v0 + h * h / 2 * u, rtol=1e-15)
    np.testing.assert_allclose(engine.v[0, :, 0], v0 + h * u, rtol=1e-15)


def test_design_uses_the_sampling_period_of_the_budget():
    policy = SampledLinearPolicy(config_for(n_intervals=25))
    assert policy.sampling_period == pytest.approx(0.8)
    assert policy.radius < 1.0
    assert policy.radius == pytest.approx(design.zoh_radius(policy.config.topology, policy.gamma, policy.gain, 0.8))
    assert "proven" in policy.guarantee()


def test_designed_law_contracts_the_disagreement_at_the_predicted_rate():
    # Long horizon at h = 0.8 s on the directed 6-ring: D(T_s) / D(0) decays like radius^K.
    config = config_for(n_intervals=400, settling_time=320.0)
    policy = SampledLinearPolicy(config)
    engine = ConsensusEngine(config, 3)
    states = [engine.sample_initial_state(np.random.default_rng(s)) for s in range(3)]
    engine.reset(np.stack([x for x, _ in states]), np.stack([v for _, v in states]))
    while not engine.done:
        engine.step(policy(engine.observations()))
    error = engine.batch_metrics()["relative_deadline_error"]
    assert np.all(error < policy.radius ** (400 * 0.9))


def test_switching_topology_uses_the_exact_period_product():
    config = config_for(topology="paper_fig1", n_intervals=50)
    policy = SampledLinearPolicy(config)
    assert policy.radius == pytest.approx(design.zoh_radius(config.topology, policy.gamma, policy.gain, 0.4))
    assert policy.radius < 1.0
