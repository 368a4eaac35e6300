"""The ParallelEnv's small-N path (fxc_env.envs.small_n) gives the engine's numbers bit for bit.

Each test plays the same episode twice, once on the small-N path and once with
``small_n_path = False`` (every interval through ConsensusEngine.step), and compares
observations, rewards, terminations, truncations, infos (keys and values), ``state()`` and
the episode metrics exactly.
"""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

import fxc_env
from fxc_env.core.validation import ArgumentError
from fxc_env.envs import small_n


def _env(small: bool, **kwargs):
    env = fxc_env.parallel_env(**kwargs)
    env.unwrapped.small_n_path = small
    return env


def _same(a, b) -> bool:
    """Equal in type, keys, shape, dtype and every bit (nan equal to nan)."""
    if isinstance(a, dict):
        return type(b) is dict and list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return type(a) is type(b) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        return type(b) is np.ndarray and a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, float):
        return type(b) is float and (a == b or (a != a and b != b)) and np.copysign(1, a) == np.copysign(1, b)
    return type(a) is type(b) and a == b


def _episode(small: bool, seed: int, scale: float = 1.0, **kwargs) -> tuple[list, bool]:
    """Every return of reset and step, state() after each step, and the engine's metrics at the end."""
    env = _env(small, **kwargs)
    record: list = [env.reset(seed=seed)]
    space = env.action_space(env.possible_agents[0])
    rng = np.random.default_rng(seed)
    taken = env.unwrapped._small is not None
    while env.agents:
        actions = {agent: (scale * rng.uniform(space.low, space.high)).astype(space.dtype) for agent in env.agents}
        record += [env.step(actions), env.state()]
    record.append(env.unwrapped.engine.batch_metrics())
    return record, taken


CASES = [
    {"scenario": "paper_fig1"},
    {"scenario": "paper_fig1", "obs_mode": "raw"},
    {"scenario": "paper_fig1", "action_mode": "accel"},
    {"scenario": "paper_fig1", "action_mode": "accel", "obs_mode": "raw"},
    {"scenario": "paper_fig1", "obs_dtype": "float32", "global_state": "normalized"},
    {"scenario": "paper_fig1", "obs_slots": 3, "obs_format": "dict"},
    {"scenario": "paper_fig1", "max_cycles": 17},
    {"scenario": "paper_fig1", "formation_offsets": np.arange(6.0)[:, None]},
    {"topology": "random", "n_agents": 12, "mean_in_degree": 3.0, "topology_period": 2},
    {"topology": "ring", "n_agents": 5, "schedule": "uniform", "n_intervals": 30},
    {"topology": {"family": "ring"}, "n_agents": 4},
    {"scenario": "paper_fig1", "action_mode": "plan_balanced", "n_intervals": 50},
    {"scenario": "paper_fig1", "action_mode": "plan_balanced", "obs_mode": "raw"},
    {"topology": "random", "n_agents": 12, "mean_in_degree": 3.0, "action_mode": "plan_balanced"},
]


@pytest.mark.parametrize("kwargs", CASES, ids=[repr(case)[:60] for case in CASES])
def test_small_n_episodes_are_the_engines_bit_for_bit(kwargs):
    fast, taken = _episode(True, seed=3, **kwargs)
    assert taken, "the small-N path did not apply"
    slow, _ = _episode(False, seed=3, **kwargs)
    assert _same(fast, slow)


def test_the_paper_example_takes_the_small_n_path_and_larger_or_other_envs_do_not():
    env = fxc_env.parallel_env(scenario="paper_fig1")
    env.reset(seed=0)
    assert env.unwrapped._small is not None  # the path the throughput goal is measured on
    for kwargs in (
        {"topology": "random", "n_agents": small_n.SMALL_N + 1},
        {"scenario": "paper_fig1", "dim": 2},
        {"scenario": "paper_fig1", "u_max": 1.0},
        {"scenario": "paper_fig1", "obs_noise": 0.01},
        {"scenario": "paper_fig1", "link_dropout": 0.1},
        {"scenario": "paper_fig1", "switching": "random"},
        {"scenario": "paper_fig1", "agent_model": "single_integrator"},
    ):
        env = fxc_env.parallel_env(**kwargs)
        env.reset(seed=0)
        assert env.unwrapped._small is None, kwargs


def test_bad_actions_on_the_small_n_path_raise_naming_them_and_change_nothing():
    env = _env(True, scenario="paper_fig1")
    env.reset(seed=1)
    good = {agent: np.zeros(2) for agent in env.agents}
    env.step(good)
    before = (env.unwrapped.engine.state.copy(), env.unwrapped.engine.k, env.state().copy())
    bad_cases = [
        ({**good, "agent_9": np.zeros(2)}, "unknown agent"),
        ({agent: good[agent] for agent in env.agents[:-1]}, "missing an action"),
        ({**good, "agent_2": np.zeros(3)}, "agent_2"),
        ({**good, "agent_4": np.array([0.0, np.nan])}, "agent_4"),
        ({**good, "agent_0": np.array([np.inf, 0.0], dtype=np.float32)}, "agent_0"),
        ({**good, "agent_1": "0.5"}, "agent_1"),
    ]
    for actions, named in bad_cases:
        with pytest.raises(ArgumentError, match=named):
            env.step(actions)
        after = (env.unwrapped.engine.state, env.unwrapped.engine.k, env.state())
        assert np.array_equal(before[0], after[0]) and before[1] == after[1] and np.array_equal(before[2], after[2])


def test_an_overflowing_interval_is_refused_as_the_engine_refuses_it():
    messages = []
    for small in (True, False):
        env = _env(small, scenario="paper_fig1", obs_mode="raw", action_bound=1e300)
        env.reset(seed=2)
        state = env.state().copy()
        with pytest.raises(ArgumentError, match="overflow float64") as caught:
            env.step({agent: np.array([1e300, -1e300]) for agent in env.agents})
        assert np.array_equal(env.state(), state) and env.unwrapped.engine.k == 0
        messages.append(str(caught.value))
    assert messages[0] == messages[1]


def test_other_action_types_and_a_state_set_on_the_engine_are_followed():
    """Lists, ints and float16 go through the full check; a state written into the engine is read back."""
    records = []
    for small in (True, False):
        env = _env(small, scenario="paper_fig1")
        env.reset(seed=4)
        steps = [env.step({agent: [0.5, -0.25] for agent in env.agents})]
        steps.append(env.step({agent: np.array([1, 0]) for agent in env.agents}))
        steps.append(env.step({agent: np.array([0.5, 0.5], dtype=np.float16) for agent in env.agents}))
        env.unwrapped.engine.state[0, :, 0, 0] += np.arange(6.0)
        steps.append(env.step({agent: np.array([0.3, 0.1]) for agent in env.agents}))
        records.append((steps, env.state(), env.unwrapped.engine.batch_metrics()))
    assert _same(records[0], records[1])


@pytest.mark.parametrize("duplicate", [copy.deepcopy, lambda env: pickle.loads(pickle.dumps(env))])
def test_a_copy_made_mid_episode_continues_bit_for_bit(duplicate):
    env = _env(True, scenario="paper_fig1")
    env.reset(seed=5)
    actions = [{agent: np.full(2, 0.1 * (i % 3)) for agent in env.agents} for i in range(200)]
    for step in actions[:50]:
        env.step(step)
    twin = duplicate(env)
    rest = [env.step(step) for step in actions[50:]]
    twin_rest = [twin.step(step) for step in actions[50:]]
    assert _same(rest, twin_rest) and not env.agents and not twin.agents
