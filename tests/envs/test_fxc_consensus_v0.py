"""PettingZoo compliance: the official API tests over every scenario and mode, and the AEC form's own contract."""

from __future__ import annotations

import functools
import pickle
import re
import types
import warnings

import numpy as np
import pytest
from helpers import ACTION_MODES, MODES, OBS_MODES
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, render_test, state_test

import fxc_env
from fxc_env import ReferencePolicy, fxc_consensus_v0
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.aec import ConsensusAECEnv
from fxc_env.envs.parallel import ConsensusParallelEnv

SCENARIO_NAMES = sorted(fxc_env.SCENARIOS)
#: K for the API runs: long enough to reach the deadline inside the test's cycles, and fast.
K = 40


def _slow_unless(fast: bool) -> tuple:
    return () if fast else (pytest.mark.slow,)


#: The scenarios `make check` runs through the API tests: each mode once, taken in turn. The
#: formations (the general agents' path, covered by test_agent_models) run in `make test`.
FAST_SCENARIOS = [name for name in SCENARIO_NAMES if not name.startswith("formation_")]
#: Every scenario in every mode; `make check` (not slow) keeps each of FAST_SCENARIOS once.
ALL = [
    pytest.param(
        scenario,
        action_mode,
        obs_mode,
        id=f"{scenario}-{action_mode}-{obs_mode}",
        marks=_slow_unless(
            scenario in FAST_SCENARIOS and (action_mode, obs_mode) == MODES[FAST_SCENARIOS.index(scenario) % len(MODES)]
        ),
    )
    for scenario in SCENARIO_NAMES
    for action_mode in ACTION_MODES
    for obs_mode in OBS_MODES
]
#: max_cycles_test plays whole default-length episodes: `make check` keeps the 6-agent ring in each mode.
RING_ONLY = [
    pytest.param(
        scenario,
        action_mode,
        obs_mode,
        id=f"{scenario}-{action_mode}-{obs_mode}",
        marks=_slow_unless(scenario == "ring_6"),
    )
    for scenario in SCENARIO_NAMES
    for action_mode in ACTION_MODES
    for obs_mode in OBS_MODES
]


@pytest.fixture(autouse=True)
def _quiet_pettingzoo_warnings():
    # The official tests warn about unbounded raw observations and negative states; the
    # asserts are what matter here.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def test_entry_points():
    assert isinstance(fxc_env.parallel_env(), ParallelEnv)
    assert isinstance(fxc_env.env(), AECEnv)
    assert fxc_env.raw_env is fxc_consensus_v0.raw_env is ConsensusAECEnv
    raw = fxc_consensus_v0.raw_env()
    assert isinstance(raw, AECEnv) and raw.unwrapped is raw  # the unwrapped AEC env, PettingZoo's convention
    assert isinstance(fxc_env.env().unwrapped, ConsensusAECEnv)
    assert fxc_env.parallel_env().metadata["name"] == raw.metadata["name"] == "fxc_consensus_v0"


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"obs_format": "dict", "obs_dtype": "float32"},
        {"global_state": "normalized", "scenario": "random_20_planar"},
    ],
)
def test_raw_env_passes_the_aec_api_test(kwargs):
    api_test(fxc_env.raw_env(n_intervals=K, **kwargs), num_cycles=60)
    state_test(fxc_env.env(n_intervals=K, **kwargs), fxc_env.parallel_env(n_intervals=K, **kwargs), num_cycles=K + 5)


@pytest.mark.parametrize(("scenario", "action_mode", "obs_mode"), ALL)
def test_parallel_api(scenario, action_mode, obs_mode):
    env = fxc_env.parallel_env(scenario=scenario, action_mode=action_mode, obs_mode=obs_mode, n_intervals=K)
    parallel_api_test(env, num_cycles=K + 5)  # reaches termination
    env = fxc_env.parallel_env(scenario=scenario, action_mode=action_mode, obs_mode=obs_mode, n_intervals=K)
    parallel_api_test(env, num_cycles=K // 2)  # truncated by max_cycles, which the test sets


@pytest.mark.parametrize(("scenario", "action_mode", "obs_mode"), ALL)
def test_aec_api(scenario, action_mode, obs_mode):
    api_test(fxc_env.env(scenario=scenario, action_mode=action_mode, obs_mode=obs_mode, n_intervals=K), num_cycles=60)


@pytest.mark.parametrize(("scenario", "action_mode", "obs_mode"), ALL)
def test_state(scenario, action_mode, obs_mode):
    kwargs = {"scenario": scenario, "action_mode": action_mode, "obs_mode": obs_mode, "n_intervals": K}
    state_test(fxc_env.env(**kwargs), fxc_env.parallel_env(**kwargs), num_cycles=K + 5)


@pytest.mark.parametrize(("scenario", "action_mode", "obs_mode"), ALL)
def test_dict_observations_pass_the_api_tests(scenario, action_mode, obs_mode):
    kwargs = {
        "scenario": scenario,
        "action_mode": action_mode,
        "obs_mode": obs_mode,
        "obs_format": "dict",
        "n_intervals": K,
    }
    parallel_api_test(fxc_env.parallel_env(**kwargs), num_cycles=K + 5)
    api_test(fxc_env.env(**kwargs), num_cycles=60)


def test_default_settings_pass_the_api_tests():
    # The defaults (K = 200), once, through the whole episode.
    parallel_api_test(fxc_env.parallel_env(), num_cycles=205)
    api_test(fxc_env.env(), num_cycles=205)


def test_max_cycles_on_the_module():
    max_cycles_test(fxc_consensus_v0)


def _module_with(**kwargs):
    """A stand-in for the module whose ``env``/``parallel_env`` carry extra settings."""
    return types.SimpleNamespace(
        env=functools.partial(fxc_env.env, **kwargs),
        parallel_env=functools.partial(fxc_env.parallel_env, **kwargs),
    )


@pytest.mark.parametrize(("scenario", "action_mode", "obs_mode"), RING_ONLY)
def test_max_cycles(scenario, action_mode, obs_mode):
    max_cycles_test(_module_with(scenario=scenario, action_mode=action_mode, obs_mode=obs_mode))


@pytest.mark.slow  # matplotlib frames of whole episodes; test_rendering.py covers rendering in make check
@pytest.mark.parametrize("scenario", SCENARIO_NAMES)
def test_render(scenario):
    def env_fn(render_mode=None):
        return fxc_env.env(scenario=scenario, render_mode=render_mode, n_intervals=K)

    def not_blank(frame):
        return len(np.unique(frame.reshape(-1, 3), axis=0)) > 2

    render_test(env_fn, custom_tests={"rgb_array": not_blank})


def test_render_modes_in_metadata():
    assert set(fxc_env.parallel_env().metadata["render_modes"]) == {"human", "rgb_array"}


def test_importing_fxc_env_registers_both_forms_with_pettingzoo():
    import pettingzoo

    from fxc_env.envs.parallel import ConsensusParallelEnv

    parallel = pettingzoo.make("parallel", "fxc_consensus_v0", scenario="paper_fig1")
    assert isinstance(parallel, ConsensusParallelEnv)
    assert parallel.metadata["name"] == "fxc_consensus_v0" == fxc_env.ENV_ID
    aec = pettingzoo.make("aec", "fxc_consensus_v0", n_intervals=5)
    assert isinstance(aec.unwrapped, ConsensusAECEnv) and aec.unwrapped.config.n_intervals == 5
    aec.reset(seed=0)
    assert aec.agent_selection == "agent_0"


# ----------------------------------------------------------------- the AEC form


def aec_cycle(aec, actions):
    """One cycle: every live agent acts in turn with ``actions[agent]``."""
    for _ in range(len(aec.agents)):
        aec.step(actions[aec.agent_selection])


def test_the_aec_form_plays_the_parallel_episode_with_its_rewards_and_infos():
    aec, parallel = (
        fxc_env.raw_env(scenario="random_20_planar", n_intervals=8),
        fxc_env.parallel_env(scenario="random_20_planar", n_intervals=8),
    )
    aec.reset(seed=3)
    observations, _ = parallel.reset(seed=3)
    policy = ReferencePolicy(parallel)
    assert aec.num_agents == aec.max_num_agents == 20
    total = 0.0
    while parallel.agents:
        for agent in parallel.agents:
            np.testing.assert_array_equal(aec.observe(agent), observations[agent])
        actions = {agent: policy(obs) for agent, obs in observations.items()}
        observations, rewards, terminations, truncations, infos = parallel.step(actions)
        aec_cycle(aec, actions)
        total += rewards["agent_0"]
        np.testing.assert_array_equal(aec.state(), parallel.state())
        assert aec.rewards == rewards and aec.terminations == terminations and aec.truncations == truncations
        assert aec.infos.keys() == infos.keys()
        _, reward, terminated, truncated, info = aec.last()
        assert reward == rewards["agent_0"] and terminated == terminations["agent_0"] and not truncated
        assert info["t"] == infos["agent_0"]["t"]
    assert info["episode"] == pytest.approx(infos["agent_0"]["episode"])
    assert total > 0
    # Every agent leaves with one step(None); then the episode is over.
    removed = []
    while aec.agents:
        removed.append(aec.agent_selection)
        aec.step(None)
    assert removed == aec.possible_agents and aec.num_agents == 0
    with pytest.raises(RuntimeError, match="reset"):
        aec.step(np.zeros(4))


BAD_AEC_ACTIONS = [
    ("nan", np.array([np.nan, 0.0]), ArgumentError),
    ("inf", np.array([0.0, np.inf]), ArgumentError),
    ("too long", np.zeros(3), ArgumentError),
    ("scalar", 0.5, ArgumentError),
    ("string", "up", TypeError),
    ("none", None, TypeError),
    ("ragged", [[0.0], [1.0, 2.0]], TypeError),
]


@pytest.mark.parametrize(("label", "action", "error"), BAD_AEC_ACTIONS, ids=[b[0] for b in BAD_AEC_ACTIONS])
def test_a_bad_action_raises_when_its_agent_acts_and_is_not_stored(label, action, error):
    env, twin = fxc_env.env(scenario="paper_fig1"), fxc_env.env(scenario="paper_fig1")
    policy = ReferencePolicy(env)
    for each in (env, twin):
        each.reset(seed=0)
    good = {agent: policy(env.observe(agent)) for agent in env.agents}
    for agent in ("agent_0", "agent_1"):
        env.step(good[agent])
        twin.step(good[agent])
    assert env.agent_selection == "agent_2"
    with pytest.raises(error, match=re.escape("action of agent_2")):
        env.step(action)
    assert env.agent_selection == "agent_2"  # the same agent acts again
    np.testing.assert_array_equal(env.state(), twin.state())
    for agent in env.possible_agents[2:]:
        env.step(good[agent])
        twin.step(good[agent])
    np.testing.assert_array_equal(env.state(), twin.state())
    assert env.rewards == twin.rewards and env.unwrapped.parallel.engine.k == 1


def test_a_dead_agent_takes_only_none():
    env = fxc_env.env(scenario="paper_fig1", n_intervals=2)
    env.reset(seed=0)
    for _ in range(2):
        aec_cycle(env, {agent: np.zeros(2) for agent in env.possible_agents})
    assert all(env.terminations.values())
    with pytest.raises(ArgumentError, match=r"action of agent_0.*None"):
        env.step(np.zeros(2))
    assert env.num_agents == 6
    env.step(None)
    assert env.num_agents == 5


def test_observe_unknown_agent_and_before_reset():
    raw = fxc_env.raw_env()
    with pytest.raises(RuntimeError, match="reset"):
        raw.observe("agent_0")
    raw.reset(seed=0)
    with pytest.raises(ArgumentError, match="leader"):
        raw.observe("leader")


def test_render_before_reset_raises_and_after_reset_draws():
    raw = fxc_env.raw_env(render_mode="rgb_array", n_intervals=5)
    with pytest.raises(RuntimeError, match="reset"):
        raw.render()
    raw.reset(seed=0)
    assert raw.render().shape[2] == 3
    raw.close()


def test_a_bad_reset_leaves_the_aec_env_as_it_was():
    env = fxc_env.raw_env(scenario="paper_fig1")
    env.reset(seed=0)
    env.step(np.zeros(2))
    before = (env.agent_selection, env.state().copy(), dict(env._cumulative_rewards))
    for kwargs in ({"seed": "abc"}, {"seed": -1}, {"options": {"x0": [[0.0], [1.0, 2.0]]}}):
        with pytest.raises(ArgumentError):
            env.reset(**kwargs)
    assert env.agent_selection == before[0] and np.array_equal(env.state(), before[1])
    assert env._cumulative_rewards == before[2]


def test_aec_env_pickles_mid_cycle_and_continues_identically():
    env = fxc_env.raw_env(scenario="random_20_planar", n_intervals=6)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(27):  # one cycle and seven agents
        env.step(rng.uniform(-2, 2, size=4))
    copy = pickle.loads(pickle.dumps(env))
    assert copy.agent_selection == env.agent_selection == "agent_7"
    while env.agents:
        action = None if env.terminations[env.agent_selection] else rng.uniform(-2, 2, size=4)
        env.step(action)
        copy.step(action)
        assert copy.rewards == env.rewards and np.array_equal(copy.state(), env.state())
    assert copy.agents == []
    fresh = fxc_env.raw_env()
    a, b = pickle.loads(pickle.dumps(fresh)), pickle.loads(pickle.dumps(fresh))
    a.reset()
    b.reset()
    assert not np.array_equal(a.state(), b.state())  # copies made before any reset draw their own episodes


def test_the_env_card_is_the_help_of_every_entry_point():
    for entry in (fxc_env.env, fxc_env.parallel_env):
        assert "ConsensusParallelEnv" in entry.__doc__ or "parallel_env" in entry.__doc__
    assert ConsensusParallelEnv.__doc__.split("## Description", 1)[1] in ConsensusAECEnv.__doc__
