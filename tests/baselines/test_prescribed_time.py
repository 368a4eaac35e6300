"""The prescribed-time law (Wang, Song, Hill & Krstic 2019 family): gains, cut-off, convergence."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ConsensusEngine, make_config
from fxc_env.baselines.laws.prescribed_time import PrescribedTimePolicy

#: Complete graph on 4 agents: every nonzero Laplacian eigenvalue is 4.
COMPLETE_4 = [(j, i) for i in range(4) for j in range(4) if i != j]


def complete_config(**kwargs):
    return make_config(topology=COMPLETE_4, action_mode="accel", obs_mode="raw", **kwargs)


def observation(config, dx, dv, t_over_ts):
    """Agent 0's flat observation with rows (dx_r, dv_r), all rows real, at t_k = t_over_ts T_s."""
    layout = config.layout
    obs = np.zeros(layout.size)
    rows = obs[: layout.rows_end].reshape(layout.slots, 2)
    rows[:, 0], rows[:, 1] = dx, dv
    obs[layout.rows_end : layout.mask_end] = 1.0
    obs[layout.mask_end :] = [t_over_ts, 1.0 / config.n_intervals, 0.0]
    return obs


def test_gains_place_the_slowest_mode_exponents_at_p_and_p_plus_one():
    policy = PrescribedTimePolicy(complete_config(), exponent=3.0)
    # lambda_min = 4: k_v = 2 p / 4 = 1.5, k_x = p (p + 1) / 4 = 3; every mode has exponents 3 and 4.
    assert policy.velocity_gain == pytest.approx(1.5)
    assert policy.position_gain == pytest.approx(3.0)
    assert policy.mode_exponent == pytest.approx(3.0)


def test_law_matches_a_hand_computed_case():
    config = complete_config(settling_time=20.0, n_intervals=100, schedule="uniform")
    policy = PrescribedTimePolicy(config, exponent=3.0, cutoff=0.5)
    # t_k = 15 s: sigma = 5 s; u = k_x sum dx / sigma^2 + k_v sum dv / sigma = 3 (2) / 25 + 1.5 (-1) / 5 = -0.06
    action = policy(observation(config, dx=[1.0, 2.0, -1.0], dv=[0.5, -2.0, 0.5], t_over_ts=0.75))
    np.testing.assert_allclose(action, [-0.06, -0.06], rtol=1e-13)


def test_gain_is_frozen_at_the_cutoff():
    config = complete_config(settling_time=20.0, n_intervals=100, schedule="uniform")
    policy = PrescribedTimePolicy(config, cutoff=0.5)
    dx, dv = [1.0, 2.0, -1.0], [0.5, -2.0, 0.5]
    at_cutoff = policy(observation(config, dx, dv, 1 - 0.5 / 20))
    later = policy(observation(config, dx, dv, 1 - 0.1 / 20))
    earlier = policy(observation(config, dx, dv, 1 - 1.0 / 20))
    np.testing.assert_array_equal(later, at_cutoff)
    assert not np.allclose(earlier, at_cutoff)


def test_default_cutoff_keeps_the_hold_five_times_finer_than_the_fastest_mode():
    config = complete_config(n_intervals=4000, schedule="uniform")
    policy = PrescribedTimePolicy(config)
    h = config.settling_time / 4000
    assert policy.cutoff == pytest.approx(h * policy.velocity_gain * 4.0 / 0.2)


def test_settles_by_the_deadline_on_an_undirected_graph():
    config = complete_config(n_intervals=4000, schedule="uniform")
    policy = PrescribedTimePolicy(config)
    assert policy.guarantee().startswith("proven")
    engine = ConsensusEngine(config, 3)
    states = [engine.sample_initial_state(np.random.default_rng(s)) for s in range(3)]
    engine.reset(np.stack([x for x, _ in states]), np.stack([v for _, v in states]))
    while not engine.done:
        engine.step(policy(engine.observations()))
    metrics = engine.batch_metrics()
    # D ~ (sigma / T_s)^(p-1) (velocities lag positions by one power) down to the cut-off; constant gains then shrink it.
    assert np.all(metrics["relative_deadline_error"] < (policy.cutoff / config.settling_time) ** 2)


def test_normalized_observations_give_the_same_motion_as_raw():
    kwargs = {"n_intervals": 200, "schedule": "uniform", "action_mode": "accel"}
    configs = [make_config(topology="ring", n_agents=5, obs_mode=mode, **kwargs) for mode in ("raw", "normalized")]
    rng = np.random.default_rng(7)
    x0, v0 = rng.normal(size=(1, 5, 1)), rng.normal(size=(1, 5, 1))
    engines = [ConsensusEngine(c) for c in configs]
    for engine in engines:
        engine.reset(x0, v0)
    policies = [PrescribedTimePolicy(c) for c in configs]
    for _ in range(150):
        for engine, policy in zip(engines, policies, strict=True):
            engine.step(policy(engine.observations()))
    np.testing.assert_allclose(engines[1].state, engines[0].state, rtol=1e-10, atol=1e-12)
