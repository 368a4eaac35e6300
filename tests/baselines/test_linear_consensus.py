"""The linear second-order law (Ren & Atkins 2007) and Yu, Chen & Cao's gain test, on the engine."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ConsensusEngine, make_config
from fxc_env.baselines.laws.linear import LinearConsensusPolicy

#: Agent 0 hears agents 1 and 2; agents 1 and 2 hear agent 0.
STAR_BACK_AND_FORTH = [(1, 0), (2, 0), (0, 1), (0, 2)]
X0 = np.array([0.0, 1.0, -3.0])
V0 = np.array([0.0, 0.5, 2.0])


def engine_at(config, x0, v0, n_episodes=1):
    engine = ConsensusEngine(config, n_episodes)
    engine.reset(
        np.broadcast_to(x0[:, None], (n_episodes, len(x0), 1)), np.broadcast_to(v0[:, None], (n_episodes, len(v0), 1))
    )
    return engine


def run_to_deadline(policy, config, seeds=range(4)):
    engine = ConsensusEngine(config, len(seeds))
    states = [engine.sample_initial_state(np.random.default_rng(s)) for s in seeds]
    engine.reset(np.stack([x for x, _ in states]), np.stack([v for _, v in states]))
    with np.errstate(all="ignore"):
        while not engine.done:
            engine.step(policy(engine.observations()))
    return engine.batch_metrics()["relative_deadline_error"]


def test_law_matches_a_hand_computed_case():
    config = make_config(topology=STAR_BACK_AND_FORTH, action_mode="accel", obs_mode="raw")
    policy = LinearConsensusPolicy(config, gamma=2.0, gain=0.5)
    actions = policy(engine_at(config, X0, V0).observations())[0]
    # u_0 = -g [(x0 - x1) + (x0 - x2) + gamma ((v0 - v1) + (v0 - v2))] = -0.5 [(-1 + 3) + 2 (-0.5 - 2)] = 1.5
    # u_1 = -0.5 [(1 - 0) + 2 (0.5 - 0)] = -1;  u_2 = -0.5 [(-3 - 0) + 2 (2 - 0)] = -0.5
    expected = np.array([1.5, -1.0, -0.5])
    np.testing.assert_allclose(actions, np.stack([expected, expected], axis=1), rtol=1e-15)


def test_normalized_observations_give_the_same_motion_as_raw():
    kwargs = {"topology": "random", "n_agents": 12, "n_intervals": 50, "schedule": "uniform", "action_mode": "accel"}
    raw, normalized = make_config(obs_mode="raw", **kwargs), make_config(obs_mode="normalized", **kwargs)
    rng = np.random.default_rng(3)
    x0, v0 = rng.normal(size=12), rng.normal(size=12)
    engines = [engine_at(c, x0, v0) for c in (raw, normalized)]
    policies = [LinearConsensusPolicy(c, gamma=1.3) for c in (raw, normalized)]
    for _ in range(20):
        for engine, policy in zip(engines, policies, strict=True):
            engine.step(policy(engine.observations()))
    np.testing.assert_allclose(engines[1].state, engines[0].state, rtol=1e-12, atol=1e-12)


def test_gain_test_bound_of_the_directed_six_ring_is_sqrt_three_halves():
    # mu = 1 - exp(i theta): Im^2 / (Re |mu|^2) = (1 + cos theta) / (2 (1 - cos theta)), largest 3/2 at theta = pi/3.
    config = make_config(topology="ring", n_agents=6, action_mode="accel", obs_mode="raw")
    policy = LinearConsensusPolicy(config)
    assert policy.gain_test_bound == pytest.approx(np.sqrt(1.5), rel=1e-12)
    assert policy.passes_gain_test


@pytest.mark.parametrize(("gamma", "converges"), [(1.5, True), (1.0, False)])
def test_converges_where_the_gain_test_passes_and_diverges_where_it_fails(gamma, converges):
    config = make_config(
        topology="ring",
        n_agents=6,
        settling_time=40.0,
        n_intervals=4000,
        schedule="uniform",
        action_mode="accel",
        obs_mode="raw",
    )
    policy = LinearConsensusPolicy(config, gamma=gamma)
    assert policy.passes_gain_test is converges  # bound sqrt(1.5) = 1.22
    error = run_to_deadline(policy, config)
    if converges:
        assert np.all(error < 1e-2)
    else:
        assert np.all(error > 10.0)


def test_designed_gamma_passes_the_test_on_every_named_digraph():
    for topology in ("ring", "path", "star", "random"):
        config = make_config(topology=topology, n_agents=20, action_mode="accel", obs_mode="raw")
        policy = LinearConsensusPolicy(config)
        assert policy.passes_gain_test, topology
        assert policy.parameters()["decay_rate"] > 0


def test_rejects_bad_gains_and_plan_mode():
    config = make_config(action_mode="accel", obs_mode="raw")
    with pytest.raises(ValueError, match="gamma"):
        LinearConsensusPolicy(config, gamma=-1.0)
    with pytest.raises(ValueError, match="gain"):
        LinearConsensusPolicy(config, gain=0.0)
    with pytest.raises(ValueError, match="action_mode"):
        LinearConsensusPolicy(make_config(action_mode="plan"))
