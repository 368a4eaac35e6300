"""One policy protocol (fxc_env.policies.protocol; docs: getting-started.md, "One policy protocol").

Every policy the project ships or registers is called ``policy(observations)`` with the parallel env's dict and
answers ``{agent: action}``; an array ``(..., N, obs_size)`` gives the same actions; one agent's observation
works for a policy without memory and is refused by name by one with; ``reset()`` forgets the memory; and
``fxc_env.rollout`` plays one episode that way.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from helpers import SHIPPED_INSIDE

import fxc_env
from fxc_env.baselines import load_policy
from fxc_env.baselines.registry import LAWS
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.learned import SHIPPED, load_learned_policy
from fxc_env.policies.protocol import flat_observation, needs_team, policy_name


def _law(name):
    """A registered law on a ring of 6 under its own settings, with few intervals (the laws' own minimum is met)."""
    law = LAWS[name]
    kwargs = {"scenario": None, "topology": "ring", "n_agents": 6, "n_intervals": 60, "schedule": law.schedule}
    env = fxc_env.parallel_env(**kwargs, action_mode=law.action_mode, obs_mode=law.obs_mode)
    return env, load_policy(name, env.config)


def _shipped(name):
    """A shipped learned policy in an environment inside its training domain."""
    env = fxc_env.parallel_env(**SHIPPED_INSIDE[name])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inside its domain: no adaptation beyond what it was trained for
        return env, load_learned_policy(name, env)


def _reference():
    env = fxc_env.parallel_env(scenario="paper_fig1")
    return env, fxc_env.ReferencePolicy(env)


CASES = {"ReferencePolicy": _reference}
CASES |= {f"law:{name}": (lambda name=name: _law(name)) for name in LAWS}
# "pretrained" is the generalist's older name (the same file).
CASES |= {f"shipped:{name}": (lambda name=name: _shipped(name)) for name in SHIPPED if name != "pretrained"}


def _play(env, policy):
    """One episode called as ``policy(observations)`` with the env's dict, checking every answer; its observations
    ``(K, N, obs_size)`` and actions ``(K, N, action_size)`` as the env's agents saw and sent them."""
    agents, size = env.possible_agents, env.action_space(env.possible_agents[0]).shape
    observations, _ = env.reset(seed=0)
    seen, sent = [], []
    while env.agents:
        actions = policy(observations)
        assert isinstance(actions, dict) and list(actions) == list(observations)
        assert all(np.shape(actions[a]) == size and np.all(np.isfinite(actions[a])) for a in agents)
        seen.append(np.stack([flat_observation(observations[a]) for a in agents]))
        sent.append(np.stack([actions[a] for a in agents]))
        observations, _, _, _, infos = env.step(actions)
    assert np.isfinite(infos[agents[0]]["episode"]["relative_deadline_error"])
    return np.asarray(seen), np.asarray(sent)


@pytest.mark.parametrize("case", list(CASES))
def test_every_policy_plays_an_episode_called_with_the_env_dict_and_an_array_gives_the_same_actions(case):
    env, policy = CASES[case]()
    seen, sent = _play(env, policy)
    assert len(seen) == env.config.n_intervals
    policy.reset()  # a second episode from its start: the same actions, called with the arrays
    for obs, actions in zip(seen, sent, strict=True):
        assert np.array_equal(policy(obs), actions)


@pytest.mark.parametrize("case", list(CASES))
def test_one_agents_observation_is_answered_without_memory_and_refused_by_name_with_it(case):
    env, policy = CASES[case]()
    observations, _ = env.reset(seed=0)
    team = policy(observations)
    one = observations[env.possible_agents[0]]
    if needs_team(policy):
        with pytest.raises(ArgumentError, match=r"^observations: (.*) acts for every agent at once") as refused:
            policy(one)
        message = str(refused.value)
        assert policy_name(policy) in message and "whole dict" in message and "(..., N, " in message
    else:
        assert np.allclose(policy(one), team[env.possible_agents[0]], rtol=1e-6, atol=1e-12)


def test_a_memory_law_refused_agent_by_agent_plays_on_unchanged():
    env, policy = _law("signalling")
    _, first = _play(env, policy)
    observations, _ = env.reset(seed=0)
    env.step(policy(observations))
    with pytest.raises(ArgumentError, match=r"^observations: SignallingPolicy \(signalling\) acts for every agent"):
        policy(observations["agent_0"])
    policy.reset()
    _, second = _play(env, policy)
    assert np.array_equal(first, second)


@pytest.mark.parametrize("name", ["reference", "signalling"])
def test_dict_format_observations_are_told_from_the_team_dict(name):
    law = LAWS[name]
    env = fxc_env.parallel_env(
        obs_format="dict", schedule=law.schedule, action_mode=law.action_mode, obs_mode=law.obs_mode
    )
    flat = fxc_env.parallel_env(schedule=law.schedule, action_mode=law.action_mode, obs_mode=law.obs_mode)
    policy = load_policy(name, env.config)
    assert np.array_equal(_play(env, policy)[1], _play(flat, policy)[1])
    observations, _ = env.reset(seed=0)
    if not needs_team(policy):  # one agent's dict observation (its keys: neighbours, mask, clock) is one agent's
        assert np.array_equal(policy(observations["agent_0"]), policy(observations)["agent_0"])


def test_a_team_dict_of_unequal_observations_is_refused_by_name():
    env, policy = _reference()
    observations, _ = env.reset(seed=0)
    observations["agent_1"] = observations["agent_1"][:-1]
    with pytest.raises(ArgumentError, match=r"^observations: every agent's observation must have one shape"):
        policy(observations)


def test_rollout_plays_one_episode_and_returns_the_env_s_episode_infos_and_trajectory():
    env = fxc_env.parallel_env(scenario="paper_fig1")
    policy = fxc_env.ReferencePolicy(env)
    seen, sent = _play(env, policy)
    observations, _ = env.reset(seed=0)
    while env.agents:
        observations, _, _, _, infos = env.step(policy(observations))
    episode_infos = infos["agent_0"]["episode"]
    episode, steps = fxc_env.rollout(env, policy, seed=0, trajectory=True)
    assert episode == episode_infos and episode["relative_deadline_error"] < 1e-11
    assert fxc_env.rollout(env, policy, seed=0) == episode
    assert np.array_equal(steps["observations"], seen) and np.array_equal(steps["actions"], sent)
    assert steps["rewards"].shape == (200, 6) and np.all(steps["rewards"] == steps["rewards"][:, :1])


def test_rollout_resets_the_policy_first_and_takes_a_plain_function_too():
    env = fxc_env.parallel_env(scenario="paper_fig1")
    reference, calls = fxc_env.ReferencePolicy(env), []

    class Recorder:
        def reset(self):
            calls.append("reset")

        def __call__(self, observations):
            calls.append("call")
            return reference(observations)

    episode = fxc_env.rollout(env, Recorder(), seed=0)
    assert calls == ["reset"] + ["call"] * 200
    assert fxc_env.rollout(env, lambda observations: reference(observations), seed=0) == episode


@pytest.mark.parametrize(
    ("keywords", "message"),
    [
        ({"env": "aec"}, r"^env: expected a PettingZoo parallel env \(fxc_env.parallel_env\(...\)\), got"),
        ({"policy": 3}, r"^policy: expected a policy called as policy\(observations\), got int"),
        ({"seed": -1}, r"^seed: "),
        ({"seed": 1.5}, r"^seed: "),
        ({"trajectory": "yes"}, r"^trajectory: expected True or False, got 'yes'"),
    ],
)
def test_rollout_refuses_bad_arguments_by_name_before_anything_is_reset(keywords, message):
    env = fxc_env.parallel_env(scenario="paper_fig1")
    arguments = {"env": env, "policy": fxc_env.ReferencePolicy(env), "seed": 0, **keywords}
    if arguments["env"] == "aec":
        arguments["env"] = fxc_env.env(scenario="paper_fig1")
    with pytest.raises(ArgumentError, match=message):
        fxc_env.rollout(**arguments)
    with pytest.raises(RuntimeError, match="reset"):  # the env was never reset
        env.state()
