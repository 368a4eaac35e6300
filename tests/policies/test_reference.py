"""The paper's controller (eq. 11) as a policy on local observations, through the public API."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    MODES,
    MODES_DEFAULT_FAST,
    PAPER_V0,
    PAPER_V_STAR,
    PAPER_X0,
    PAPER_X_STAR,
    reference_actions,
)

import fxc_env
from fxc_env import ReferencePolicy, make_config


def collect_observations(env, steps, seed=0):
    """Observations of every agent at the first ``steps`` instants under the reference."""
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=seed)
    seen = [obs]
    for _ in range(steps):
        obs, *_ = env.step(reference_actions(policy, obs))
        seen.append(obs)
    return seen


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
@pytest.mark.parametrize("scenario", ["paper_fig1", "random_20_planar"])
def test_batch_with_leading_dimensions_equals_per_agent(scenario, action_mode, obs_mode):
    env = fxc_env.parallel_env(scenario=scenario, action_mode=action_mode, obs_mode=obs_mode)
    policy = ReferencePolicy(env)
    seen = collect_observations(env, 5)
    agents = env.possible_agents
    batch = np.array([[obs[a] for a in agents] for obs in seen])  # (6 instants, N, obs_size)
    batch = batch.reshape(2, 3, len(agents), -1)
    actions = policy(batch)
    assert actions.shape == (2, 3, len(agents), 2 * env.config.dim)
    for t, obs in enumerate(seen):
        for i, a in enumerate(agents):
            single = policy(obs[a])
            assert single.shape == (2 * env.config.dim,)
            np.testing.assert_allclose(actions.reshape(6, len(agents), -1)[t, i], single, rtol=1e-15, atol=0)


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
def test_dict_observations_give_the_same_actions(action_mode, obs_mode):
    kwargs = {"scenario": "random_20_planar", "action_mode": action_mode, "obs_mode": obs_mode}
    flat_env = fxc_env.parallel_env(**kwargs)
    dict_env = fxc_env.parallel_env(obs_format="dict", **kwargs)
    flat_seen = collect_observations(flat_env, 4)
    dict_seen = collect_observations(dict_env, 4)
    policy = ReferencePolicy(dict_env)
    for flat_obs, dict_obs in zip(flat_seen, dict_seen, strict=True):
        for a in flat_env.possible_agents:
            np.testing.assert_array_equal(policy(dict_obs[a]), policy(flat_obs[a]))
        # A batch of dict observations (leading agent axis).
        stacked = {key: np.stack([dict_obs[a][key] for a in dict_env.possible_agents]) for key in dict_obs["agent_0"]}
        np.testing.assert_array_equal(
            policy(stacked), np.stack([policy(flat_obs[a]) for a in flat_env.possible_agents])
        )


def test_policy_accepts_parallel_aec_env_and_config():
    config = make_config("paper_fig1")
    for source in (fxc_env.parallel_env(scenario="paper_fig1"), fxc_env.env(scenario="paper_fig1"), config):
        assert ReferencePolicy(source).config.n_agents == 6
    with pytest.raises(TypeError, match="ReferencePolicy"):
        ReferencePolicy(object())


def run_public_episode(**kwargs):
    """reset/step with dict actions from the reference: the ParallelEnv API alone."""
    env = fxc_env.parallel_env(**kwargs)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    infos = {}
    while env.agents:
        actions = {agent: policy(obs[agent]) for agent in env.agents}
        for agent, action in actions.items():
            assert env.action_space(agent).contains(action), (agent, action)
        obs, _, _, _, infos = env.step(actions)
    return env, infos


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
def test_paper_numbers_through_the_parallel_env(action_mode, obs_mode):
    env, infos = run_public_episode(scenario="paper_fig1", action_mode=action_mode, obs_mode=obs_mode)
    state = env.state()
    np.testing.assert_allclose(state[:, 0], PAPER_X_STAR, rtol=0, atol=1e-9)
    np.testing.assert_allclose(state[:, 1], PAPER_V_STAR, rtol=0, atol=1e-9)
    episode = infos["agent_0"]["episode"]
    assert episode["achieved_final_position"] == pytest.approx(PAPER_X_STAR, abs=1e-9)
    assert episode["achieved_final_velocity"] == pytest.approx(PAPER_V_STAR, abs=1e-9)
    assert episode["predicted_final_position"] == pytest.approx(PAPER_X_STAR, abs=1e-12)
    assert episode["predicted_final_velocity"] == pytest.approx(PAPER_V_STAR, abs=1e-12)
    assert episode["relative_deadline_error"] <= 1e-9


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
def test_fixed_ring_reaches_the_average_through_the_parallel_env(action_mode, obs_mode):
    # Theorem 1 on the directed 6-ring: W is doubly stochastic, so xi = 1/6 everywhere.
    env, _ = run_public_episode(scenario="ring_6", action_mode=action_mode, obs_mode=obs_mode)
    state = env.state()
    np.testing.assert_allclose(state[:, 0], PAPER_X0.mean() + 20.0 * PAPER_V0.mean(), rtol=0, atol=1e-8)
    np.testing.assert_allclose(state[:, 1], PAPER_V0.mean(), rtol=0, atol=1e-8)


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES_DEFAULT_FAST)
def test_reference_stays_inside_the_action_box(action_mode, obs_mode):
    # The action Boxes are wide enough for the reference in every mode; checked
    # along whole episodes from several random initial states (the documented ranges).
    for kwargs in ({"scenario": "random_20_planar"}, {"topology": "complete", "n_agents": 8}):
        for seed in range(3):
            env = fxc_env.parallel_env(action_mode=action_mode, obs_mode=obs_mode, **kwargs)
            policy = ReferencePolicy(env)
            obs, _ = env.reset(seed=seed)
            while env.agents:
                actions = {agent: policy(obs[agent]) for agent in env.agents}
                for agent, action in actions.items():
                    assert env.action_space(agent).contains(action), (kwargs, seed, agent, action)
                obs, *_ = env.step(actions)


def test_normalized_reference_actions_are_order_one():
    env = fxc_env.parallel_env(scenario="paper_fig1", action_mode="plan", obs_mode="normalized")
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    largest = 0.0
    while env.agents:
        actions = {agent: policy(obs[agent]) for agent in env.agents}
        largest = max(largest, max(np.max(np.abs(a)) for a in actions.values()))
        obs, *_ = env.step(actions)
    # Disagreement falls by ~12 orders of magnitude, yet the actions stay O(1) (the scale-free units of docs: environment.md, "Observation").
    assert 0.1 < largest <= 2.0


def test_agent_without_disagreement_coasts():
    # All agents agree: every observation row is zero and the reference applies no input.
    env = fxc_env.parallel_env(topology="ring", n_agents=4, n_intervals=10)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(options={"x0": np.full(4, 2.0), "v0": np.full(4, -1.0)})
    while env.agents:
        obs, _, _, _, infos = env.step({a: policy(o) for a, o in obs.items()})
        assert all(info["energy"] == 0.0 for info in infos.values())
    np.testing.assert_allclose(env.state(), np.tile([2.0 - 20.0, -1.0], (4, 1)), rtol=1e-15)


def test_raw_accel_box_holds_the_reference_on_a_20_ring():
    # The action Box again, on a fixed directed ring of 20 agents with the default settings and
    # the documented random initial ranges: the reference's raw input ends must fit the Box.
    env = fxc_env.parallel_env(topology="ring", n_agents=20, action_mode="accel", obs_mode="raw")
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    largest = 0.0
    while env.agents:
        actions = {agent: policy(obs[agent]) for agent in env.agents}
        largest = max(largest, max(np.max(np.abs(a)) for a in actions.values()))
        obs, *_ = env.step(actions)
    assert largest <= env.action_space("agent_0").high[0]
