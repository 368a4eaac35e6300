"""What every baseline shares: construction from any front end, modes, batching, dict observations."""

from __future__ import annotations

import numpy as np
import pytest

import fxc_env
from fxc_env.baselines.laws.finite_time import FiniteTimePolicy
from fxc_env.baselines.laws.linear import LinearConsensusPolicy
from fxc_env.baselines.laws.prescribed_time import PrescribedTimePolicy
from fxc_env.baselines.laws.sampled import SampledLinearPolicy

POLICIES = [LinearConsensusPolicy, SampledLinearPolicy, FiniteTimePolicy, PrescribedTimePolicy]
SETTINGS = {"scenario": "random_20_planar", "action_mode": "accel", "obs_mode": "raw", "schedule": "uniform"}


@pytest.mark.parametrize("policy_class", POLICIES)
def test_built_from_parallel_env_vec_env_or_config_alike(policy_class):
    parallel = fxc_env.parallel_env(**SETTINGS)
    vec = fxc_env.ConsensusVecEnv(2, **SETTINGS)
    config = fxc_env.make_config(**SETTINGS)
    obs = np.random.default_rng(0).normal(size=(3, config.n_agents, config.layout.size))
    obs[..., config.layout.rows_end :] = np.abs(obs[..., config.layout.rows_end :]) / 10  # mask, clock in [0, 1)
    actions = [policy_class(source)(obs) for source in (parallel, vec, config)]
    np.testing.assert_array_equal(actions[0], actions[1])
    np.testing.assert_array_equal(actions[0], actions[2])
    with pytest.raises(TypeError, match="EnvConfig"):
        policy_class(object())


@pytest.mark.parametrize("policy_class", POLICIES)
def test_batched_call_equals_per_agent_call_and_holds_the_input(policy_class):
    env = fxc_env.parallel_env(**SETTINGS)
    policy = policy_class(env)
    obs, _ = env.reset(seed=1)
    batch = np.stack([obs[a] for a in env.possible_agents])
    actions = policy(batch)
    assert actions.shape == (len(env.possible_agents), 2 * env.config.dim)
    for i, agent in enumerate(env.possible_agents):
        np.testing.assert_array_equal(policy(obs[agent]), actions[i])
    dim = env.config.dim
    np.testing.assert_array_equal(actions[:, :dim], actions[:, dim:])  # zero-order hold: u(t_k+) = u(t_{k+1}-)


@pytest.mark.parametrize("policy_class", POLICIES)
def test_dict_observations_give_the_same_actions(policy_class):
    flat_env = fxc_env.parallel_env(**SETTINGS)
    dict_env = fxc_env.parallel_env(obs_format="dict", **SETTINGS)
    flat_obs, _ = flat_env.reset(seed=2)
    dict_obs, _ = dict_env.reset(seed=2)
    policy = policy_class(dict_env)
    for agent in flat_env.possible_agents:
        np.testing.assert_array_equal(policy(dict_obs[agent]), policy(flat_obs[agent]))


@pytest.mark.parametrize("policy_class", POLICIES)
def test_every_baseline_states_law_source_graph_class_and_parameters(policy_class):
    description = policy_class(fxc_env.make_config(**SETTINGS)).describe()
    assert description["law"].startswith("u_i =")
    assert description["source"] and description["graph_class"] and description["parameters"]


@pytest.mark.parametrize("policy_class", POLICIES)
def test_plan_mode_is_refused_with_a_message_naming_action_mode(policy_class):
    with pytest.raises(ValueError, match="action_mode"):
        policy_class(fxc_env.make_config(action_mode="plan", obs_mode="raw"))


def test_policies_see_only_relative_measurements():
    # Shifting every agent by the same position and velocity changes no observation, hence no input.
    config = fxc_env.make_config(topology="random", n_agents=10, action_mode="accel", obs_mode="raw")
    rng = np.random.default_rng(5)
    x0, v0 = rng.normal(size=(1, 10, 1)), rng.normal(size=(1, 10, 1))
    for policy_class in POLICIES:
        policy = policy_class(config)
        actions = []
        for shift in (0.0, 1e3):
            engine = fxc_env.ConsensusEngine(config)
            engine.reset(x0 + shift, v0 - shift / 7)
            actions.append(policy(engine.observations()))
        np.testing.assert_allclose(actions[1], actions[0], rtol=1e-9, atol=1e-9)
