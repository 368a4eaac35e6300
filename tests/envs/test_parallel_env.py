"""The ParallelEnv contract (the environment's card): spaces, episode end, infos, state, seeding, validation."""

from __future__ import annotations

import copy
import inspect
import json
import math
import pickle
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from helpers import MODES, PAPER_V0, PAPER_X0, brute_spread, reference_actions

import fxc_env
from fxc_env import ReferencePolicy
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.parallel import ConsensusParallelEnv

# ------------------------------------------------------------------ helpers


def random_actions(env, rng):
    bound = env.action_space("agent_0").high
    return {agent: rng.uniform(-bound, bound) for agent in env.agents}


def assert_same(a, b, where=""):
    """Exact equality of nested dicts / arrays / floats (observations, infos, ...)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for key in a:
            assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert np.array_equal(a, b), where
    else:
        assert a == b or (a is None and b is None), where


def started_pair(n_steps=3, **kwargs):
    """Two identical envs, reset with the same seed and stepped alike (an env and its twin)."""
    envs = [fxc_env.parallel_env(**kwargs) for _ in range(2)]
    policy = ReferencePolicy(envs[0])
    observations = [env.reset(seed=11)[0] for env in envs]
    for _ in range(n_steps):
        observations = [
            env.step(reference_actions(policy, obs))[0] for env, obs in zip(envs, observations, strict=True)
        ]
    return envs, observations, policy


def assert_untouched_and_in_step(env, twin, obs, policy):
    """env must still equal its twin and step exactly like it."""
    np.testing.assert_array_equal(env.state(), twin.state())
    assert env.agents == twin.agents
    actions = reference_actions(policy, obs)
    out_env, out_twin = env.step(actions), twin.step(actions)
    for a, b in zip(out_env, out_twin, strict=True):
        assert_same(a, b)


# ------------------------------------------------------------ basic contract


def test_agents_spaces_and_state_layout():
    env = fxc_env.parallel_env(scenario="random_20_planar")
    assert env.possible_agents == [f"agent_{i}" for i in range(20)]
    obs, infos = env.reset(seed=0)
    assert env.agents == env.possible_agents
    layout = env.config.layout
    for agent in env.agents:
        space = env.observation_space(agent)
        assert space is env.observation_space(agent)
        assert env.action_space(agent) is env.action_space(agent)
        assert space.shape == (layout.slots * 4 + layout.slots + 3,)
        assert space.contains(obs[agent])
        act = env.action_space(agent)
        assert act.shape == (4,) and np.all(np.isfinite(act.low)) and np.all(np.isfinite(act.high))
        assert infos[agent]["t"] == 0.0 and infos[agent]["interval"] == 0
    state = env.state()
    assert state.shape == (20, 4) and env.state_space.shape == (20, 4)
    assert env.state_space.contains(state)


@pytest.mark.parametrize("dim", [1, 2])
def test_reset_options_set_the_state(dim):
    env = fxc_env.parallel_env(topology="ring", n_agents=5, dim=dim)
    rng = np.random.default_rng(0)
    x0, v0 = rng.normal(size=(5, dim)), rng.normal(size=(5, dim))
    env.reset(seed=3, options={"x0": x0, "v0": v0})
    np.testing.assert_array_equal(env.state(), np.concatenate([x0, v0], axis=1))
    if dim == 1:
        env.reset(options={"x0": x0[:, 0], "v0": v0[:, 0]})
        np.testing.assert_array_equal(env.state(), np.concatenate([x0, v0], axis=1))


def test_reset_with_only_x0_draws_v0():
    env = fxc_env.parallel_env(topology="ring", n_agents=5)
    x0 = np.arange(5.0)
    env.reset(seed=0, options={"x0": x0})
    state = env.state()
    np.testing.assert_array_equal(state[:, 0], x0)
    assert np.all(np.abs(state[:, 1]) <= 2.0) and np.any(state[:, 1] != 0)


def test_random_initial_state_respects_the_documented_ranges():
    env = fxc_env.parallel_env(topology="complete", n_agents=50, dim=2)
    seen = []
    for seed in range(5):
        env.reset(seed=seed)
        seen.append(env.state())
    seen = np.array(seen)
    assert np.all(np.abs(seen[..., :2]) <= 5.0) and np.all(np.abs(seen[..., 2:]) <= 2.0)
    assert np.max(np.abs(seen[..., :2])) > 4.0 and np.max(np.abs(seen[..., 2:])) > 1.5  # the whole range is used
    wide = fxc_env.parallel_env(topology="complete", n_agents=50, position_range=100.0, velocity_range=0.5)
    wide.reset(seed=0)
    assert np.max(np.abs(wide.state()[:, 0])) > 50 and np.max(np.abs(wide.state()[:, 1])) <= 0.5


def test_scenario_initial_state_is_the_papers():
    env = fxc_env.parallel_env(scenario="paper_fig1")
    env.reset(seed=123)
    np.testing.assert_array_equal(env.state(), np.stack([PAPER_X0, PAPER_V0], axis=1))


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
def test_termination_at_the_deadline_with_infos_and_telescoping_reward(action_mode, obs_mode):
    env = fxc_env.parallel_env(scenario="paper_fig1", action_mode=action_mode, obs_mode=obs_mode, n_intervals=40)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    times = env.config.schedule.times
    d0 = brute_spread(PAPER_X0) + 20.0 * brute_spread(PAPER_V0)
    total, energy = 0.0, 0.0
    for k in range(1, 41):
        assert env.agents == env.possible_agents
        obs, rewards, terms, truncs, infos = env.step(reference_actions(policy, obs))
        assert len(set(rewards.values())) == 1  # a team reward
        total += rewards["agent_0"]
        assert all(terms.values()) == (k == 40) and any(terms.values()) == (k == 40)
        assert not any(truncs.values())
        for info in infos.values():
            assert info["t"] == times[k] and info["interval"] == k
            assert info["energy"] >= 0 and info["peak_u"] >= 0
            energy += info["energy"]
            assert ("episode" in info) == (k == 40)
        for agent in obs:
            assert env.observation_space(agent).contains(obs[agent])
    assert env.agents == []
    assert infos["agent_0"]["t"] == 20.0
    episode = infos["agent_0"]["episode"]
    state = env.state()
    d_end = brute_spread(state[:, 0]) + 20.0 * brute_spread(state[:, 1])
    floor = 1e-12 * d0
    assert total == pytest.approx(np.log(d0 + floor) - np.log(d_end + floor), rel=1e-9)
    assert episode["relative_deadline_error"] == pytest.approx(d_end / d0, rel=1e-9)
    assert episode["energy"] == pytest.approx(energy, rel=1e-12)
    assert episode["sampling_instants"] == 40


def test_truncation_by_max_cycles():
    env = fxc_env.parallel_env(scenario="paper_fig1", max_cycles=5)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for k in range(1, 6):
        _, _, terms, truncs, infos = env.step(random_actions(env, rng))
        assert not any(terms.values())
        assert all(truncs.values()) == (k == 5) and any(truncs.values()) == (k == 5)
    assert env.agents == []
    assert infos["agent_0"]["episode"]["sampling_instants"] == 5
    with pytest.raises(RuntimeError, match="step"):
        env.step(random_actions(fxc_env.parallel_env(scenario="paper_fig1"), rng))


def test_dict_observation_format_matches_the_flat_one():
    flat = fxc_env.parallel_env(scenario="random_20_planar")
    nested = fxc_env.parallel_env(scenario="random_20_planar", obs_format="dict")
    obs_flat, _ = flat.reset(seed=5)
    obs_dict, _ = nested.reset(seed=5)
    layout = flat.config.layout
    for agent in flat.agents:
        o = obs_dict[agent]
        assert set(o) == {"neighbours", "mask", "clock"}
        assert nested.observation_space(agent).contains(o)
        np.testing.assert_array_equal(o["neighbours"].ravel(), obs_flat[agent][: layout.rows_end])
        np.testing.assert_array_equal(o["mask"], obs_flat[agent][layout.rows_end : layout.mask_end])
        np.testing.assert_array_equal(o["clock"], obs_flat[agent][layout.mask_end :])
        assert o["neighbours"].shape == (layout.slots, 4)


def test_render_without_a_mode_returns_none():
    env = fxc_env.parallel_env()
    with pytest.warns(UserWarning, match="render"):
        assert env.render() is None  # before reset too: nothing to draw in any case
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render"):
        assert env.render() is None


def test_render_before_reset_raises_a_clear_error_and_changes_nothing():
    env = fxc_env.parallel_env(render_mode="rgb_array", n_intervals=5)
    with pytest.raises(RuntimeError, match=r"reset\(\)"):
        env.render()
    env.reset(seed=0)
    assert env.render().ndim == 3


def test_infos_episode_is_numbers_only_and_one_dict_per_agent():
    env = fxc_env.parallel_env(n_intervals=5, switching="random")  # no Theorem 2 prediction: left out
    env.reset(seed=0)
    while env.agents:
        _, _, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    episodes = [info["episode"] for info in infos.values()]
    assert len({id(e) for e in episodes}) == len(episodes)
    for episode in episodes:
        assert all(isinstance(v, float | int) and not isinstance(v, bool) for v in episode.values())
        assert "predicted_final_position" not in episode and episode["t_eps_1e_6"] == math.inf
        assert "propagation_bound" not in episode and not any(math.isnan(v) for v in episode.values())
        assert isinstance(episode["sampling_instants"], int)
    episodes[0]["energy"] = -1.0
    assert episodes[1]["energy"] != -1.0


# ------------------------------------------------------ dtypes and global state


@pytest.mark.parametrize("obs_format", ["flat", "dict"])
def test_float32_observations_are_the_float64_ones_cast(obs_format):
    wide = fxc_env.parallel_env(scenario="random_20_planar", obs_format=obs_format)
    narrow = fxc_env.parallel_env(scenario="random_20_planar", obs_format=obs_format, obs_dtype="float32")
    space = narrow.observation_space("agent_0")
    for part in space.spaces.values() if obs_format == "dict" else [space]:
        assert part.dtype == np.float32
    obs_wide, _ = wide.reset(seed=2)
    obs_narrow, _ = narrow.reset(seed=2)
    policy = ReferencePolicy(wide)
    for _ in range(5):
        for agent in wide.agents:
            assert space.contains(obs_narrow[agent])
            parts = obs_narrow[agent].values() if obs_format == "dict" else [obs_narrow[agent]]
            assert all(part.dtype == np.float32 for part in parts)
            expected = wide.config.layout.flat(obs_wide[agent]).astype(np.float32)
            np.testing.assert_array_equal(narrow.config.layout.flat(obs_narrow[agent]), expected)
        actions = reference_actions(policy, obs_wide)
        obs_wide = wide.step(actions)[0]
        obs_narrow = narrow.step(actions)[0]
    np.testing.assert_array_equal(wide.state(), narrow.state())  # the engine computes in float64 either way
    assert narrow.state().dtype == np.float64


def normalized_by_hand(x, v, settling_time):
    d = brute_spread(x) + settling_time * brute_spread(v)
    rows = np.concatenate([x - x.mean(axis=0), settling_time * (v - v.mean(axis=0))], axis=1)
    return (rows / d).ravel()


@pytest.mark.parametrize("dim", [1, 2])
def test_normalized_global_state_is_scale_free_bounded_and_flat(dim):
    kwargs = {"topology": "ring", "n_agents": 5, "dim": dim, "n_intervals": 10, "global_state": "normalized"}
    env = fxc_env.parallel_env(**kwargs)
    space = env.state_space
    assert space.shape == (5 * 2 * dim + 3,) and space.dtype == np.float64
    assert np.all(space.low[:-3] == -1) and np.all(space.high == 1) and np.all(space.low[-3:] == 0)
    rng = np.random.default_rng(0)
    x0, v0 = rng.normal(size=(5, dim)), rng.normal(size=(5, dim))
    obs, _ = env.reset(options={"x0": x0, "v0": v0})
    state = env.state()
    assert space.contains(state)
    np.testing.assert_allclose(state[:-3], normalized_by_hand(x0, v0, 20.0), rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(state[-3:], [0.0, env.config.schedule.intervals[0] / 20.0, 0.0])
    assert np.max(np.abs(state[:-3])) > 0.2
    # Scaled by 1e6 and shifted by a common position and velocity: the same state.
    other = fxc_env.parallel_env(**kwargs)
    other.reset(options={"x0": 1e6 * x0 + 3.0, "v0": 1e6 * v0 - 7.0})
    np.testing.assert_allclose(other.state(), state, atol=1e-9)
    # To the deadline under the reference: inside the Box, clock k / K ends at 1.
    policy = ReferencePolicy(env)
    while env.agents:
        obs = env.step(reference_actions(policy, obs))[0]
        assert space.contains(env.state())
    assert env.state()[-1] == 1.0 and env.state()[-3] == 1.0


def test_normalized_global_state_when_everyone_agrees_is_zero_rows():
    env = fxc_env.parallel_env(topology="ring", n_agents=4, global_state="normalized", obs_dtype="float32")
    env.reset(options={"x0": np.full(4, 2.0), "v0": np.full(4, -1.0)})
    state = env.state()
    assert state.dtype == np.float32 and env.state_space.dtype == np.float32
    assert np.all(state[:-3] == 0) and env.state_space.contains(state)


def test_raw_global_state_is_the_default():
    env = fxc_env.parallel_env(topology="ring", n_agents=4, obs_dtype="float32")
    env.reset(seed=0)
    assert env.state().shape == (4, 2) and env.state().dtype == np.float64
    assert env.state_space.shape == (4, 2)


# ------------------------------------------------------------------ signature


def test_the_signature_lists_every_argument_of_make_config_with_its_default():
    config_parameters = inspect.signature(fxc_env.make_config).parameters
    for factory in (ConsensusParallelEnv, fxc_env.parallel_env, fxc_env.env, fxc_env.raw_env):
        parameters = inspect.signature(factory).parameters
        assert list(parameters) == [*config_parameters, "render_mode", "max_cycles", "graph_tensors"], factory
        for name, parameter in config_parameters.items():
            assert parameters[name].default == parameter.default, (factory, name)
            assert parameters[name].kind == parameter.kind, (factory, name)
            assert parameters[name].annotation == parameter.annotation, (factory, name)
        assert parameters["render_mode"].default is None and parameters["max_cycles"].default is None
        assert parameters["graph_tensors"].default is False
        assert all(p.kind is not inspect.Parameter.VAR_KEYWORD for p in parameters.values())


def test_the_card_has_a_row_for_every_argument_and_cites_no_internal_documents():
    card = inspect.getdoc(ConsensusParallelEnv)
    for name in inspect.signature(ConsensusParallelEnv).parameters:
        assert f"| ``{name}`` |" in card, name
    assert "| parameter | type | default | meaning |" in card
    for text in (card, inspect.getdoc(fxc_env.raw_env)):
        assert "SPEC" not in text and "issue" not in text.lower() and "training/README" not in text
    assert "eq. (11)" in card and "docs: " in card  # cites the docs site, where the README's sections went
    assert "| ``obs_dtype`` |" in inspect.getdoc(fxc_env.raw_env)  # help(raw_env) shows the card too


# ------------------------------------------------------------- determinism


def play_seeded_episode(env, seed, action_seed):
    rng = np.random.default_rng(action_seed)
    record = []
    obs, infos = env.reset(seed=seed)
    record.append((obs, infos, env.state()))
    while env.agents:
        step = env.step(random_actions(env, rng))
        record.append((*step, env.state()))
    return record


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"scenario": "random_20_planar", "action_mode": "accel", "obs_mode": "raw"},
        {"topology": "random", "n_agents": 9, "obs_format": "dict", "n_intervals": 60},
    ],
)
def test_same_seed_gives_the_same_whole_episode(kwargs):
    a = play_seeded_episode(fxc_env.parallel_env(**kwargs), seed=42, action_seed=7)
    b = play_seeded_episode(fxc_env.parallel_env(**kwargs), seed=42, action_seed=7)
    assert len(a) == len(b) == fxc_env.make_config(**kwargs).n_intervals + 1
    for k, (step_a, step_b) in enumerate(zip(a, b, strict=True)):
        for part_a, part_b in zip(step_a, step_b, strict=True):
            assert_same(part_a, part_b, where=f"step {k}")


def test_different_seeds_give_different_episodes():
    a = play_seeded_episode(fxc_env.parallel_env(), seed=1, action_seed=7)
    b = play_seeded_episode(fxc_env.parallel_env(), seed=2, action_seed=7)
    assert not np.array_equal(a[0][2], b[0][2])
    assert any(not np.array_equal(a[0][0][agent], b[0][0][agent]) for agent in a[0][0])
    assert not np.array_equal(a[-1][-1], b[-1][-1])


def test_unseeded_reset_continues_the_seeded_stream():
    env_a, env_b = fxc_env.parallel_env(), fxc_env.parallel_env()
    env_a.reset(seed=9)
    first = env_a.state()
    env_a.reset()
    second = env_a.state()
    assert not np.array_equal(first, second)
    env_b.reset(seed=9)
    env_b.reset()
    np.testing.assert_array_equal(env_b.state(), second)
    env_a.reset(seed=9)
    np.testing.assert_array_equal(env_a.state(), first)


def test_same_seed_same_episode_in_another_process():
    script = textwrap.dedent(
        """
        import json, numpy as np, fxc_env
        env = fxc_env.parallel_env(scenario="random_20_planar", n_intervals=30)
        env.reset(seed=5)
        rng = np.random.default_rng(3)
        rewards = []
        while env.agents:
            actions = {a: rng.uniform(-2, 2, size=4) for a in env.agents}
            rewards.append(env.step(actions)[1]["agent_0"])
        print(json.dumps({"state": env.state().tolist(), "rewards": rewards}))
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, env={"PYTHONHASHSEED": "12345"}
    )
    other = json.loads(result.stdout)
    env = fxc_env.parallel_env(scenario="random_20_planar", n_intervals=30)
    env.reset(seed=5)
    rng = np.random.default_rng(3)
    rewards = []
    while env.agents:
        actions = {a: rng.uniform(-2, 2, size=4) for a in env.agents}
        rewards.append(env.step(actions)[1]["agent_0"])
    assert other["rewards"] == rewards
    assert other["state"] == env.state().tolist()


@pytest.mark.parametrize("kwargs", [{}, {"scenario": "random_20_planar", "obs_mode": "raw"}])
def test_pickle_round_trip_mid_episode(kwargs):
    env = fxc_env.parallel_env(n_intervals=50, **kwargs)
    rng = np.random.default_rng(0)
    env.reset(seed=4)
    for _ in range(20):
        env.step(random_actions(env, rng))
    copy = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(copy.state(), env.state())
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    while env.agents:
        out_a = env.step(random_actions(env, rng_a))
        out_b = copy.step(random_actions(copy, rng_b))
        for a, b in zip(out_a, out_b, strict=True):
            assert_same(a, b)
        np.testing.assert_array_equal(env.state(), copy.state())
    assert copy.agents == []
    # The seeded generator travelled too: the next unseeded resets agree.
    env.reset()
    copy.reset()
    np.testing.assert_array_equal(env.state(), copy.state())


def test_copies_made_before_the_first_reset_draw_independent_episodes():
    env = fxc_env.parallel_env()
    copies = [pickle.loads(pickle.dumps(env)), pickle.loads(pickle.dumps(env)), copy.deepcopy(env), env]
    states = []
    for each in copies:
        each.reset()
        states.append(each.state())
    assert len({s.tobytes() for s in states}) == len(states)
    # Seeded, every copy replays the same episode.
    for each in copies:
        each.reset(seed=3)
    assert all(np.array_equal(each.state(), copies[0].state()) for each in copies)


def test_ezpickle_records_the_constructor_arguments():
    from gymnasium.utils import EzPickle

    env = fxc_env.parallel_env("ring_6", n_intervals=7, max_cycles=3)
    assert isinstance(env, EzPickle)
    assert env._ezpickle_kwargs["scenario"] == "ring_6" and env._ezpickle_kwargs["n_intervals"] == 7
    rebuilt = type(env)(*env._ezpickle_args, **env._ezpickle_kwargs)
    assert (
        rebuilt.config.n_intervals == 7 and rebuilt.max_cycles == 3 and rebuilt.possible_agents == env.possible_agents
    )


# --------------------------------------------------------------- validation


def _set(agent, value):
    def change(actions):
        actions[agent] = value

    return change


def _drop(agent):
    def change(actions):
        del actions[agent]

    return change


BAD_ACTIONS = [
    ("nan", _set("agent_2", np.array([np.nan, 0.0])), ValueError, "actions['agent_2']"),
    ("inf", _set("agent_2", np.array([0.0, np.inf])), ValueError, "actions['agent_2']"),
    ("-inf", _set("agent_5", np.array([-np.inf, 0.0])), ValueError, "actions['agent_5']"),
    ("too long", _set("agent_1", np.zeros(3)), ValueError, "actions['agent_1']"),
    ("2-D", _set("agent_1", np.zeros((1, 2))), ValueError, "actions['agent_1']"),
    ("scalar", _set("agent_1", 0.5), ValueError, "actions['agent_1']"),
    ("string", _set("agent_0", "up"), TypeError, "actions['agent_0']"),
    ("numeric strings", _set("agent_3", np.array(["0.5", "0.1"])), TypeError, "actions['agent_3']"),
    ("none", _set("agent_0", None), TypeError, "actions['agent_0']"),
    ("complex", _set("agent_0", np.array([1j, 0])), TypeError, "actions['agent_0']"),
    ("missing", _drop("agent_4"), ValueError, "agent_4"),
    ("unknown", _set("agent_6", np.zeros(2)), ValueError, "agent_6"),
    ("unknown name", _set("leader", np.zeros(2)), ValueError, "leader"),
]


@pytest.mark.parametrize(("label", "change", "error", "name"), BAD_ACTIONS, ids=[b[0] for b in BAD_ACTIONS])
def test_bad_actions_raise_naming_the_argument_and_leave_the_env_as_it_was(label, change, error, name):
    (env, twin), (obs, _), policy = started_pair(scenario="paper_fig1")
    actions = reference_actions(policy, obs)
    change(actions)
    with pytest.raises(error, match=re.escape(name)) as info:
        env.step(actions)
    assert "actions" in str(info.value)
    assert_untouched_and_in_step(env, twin, obs, policy)


def test_actions_that_are_not_a_dict():
    (env, twin), (obs, _), policy = started_pair()
    with pytest.raises(TypeError, match="actions"):
        env.step([np.zeros(2)] * 6)
    assert_untouched_and_in_step(env, twin, obs, policy)


BAD_OPTIONS = [
    ({"x0": np.zeros(5)}, ValueError, "x0"),
    ({"x0": np.zeros((6, 2))}, ValueError, "x0"),
    ({"x0": np.zeros((6, 1, 1))}, ValueError, "x0"),
    ({"x0": np.array([0, 0, np.nan, 0, 0, 0])}, ValueError, "x0"),
    ({"x0": np.array([0, 0, np.inf, 0, 0, 0])}, ValueError, "x0"),
    ({"x0": ["a"] * 6}, TypeError, "x0"),
    ({"x0": np.zeros(6), "v0": np.zeros(7)}, ValueError, "v0"),
    ({"v0": np.array([0, 0, 0, 0, -np.inf, 0])}, ValueError, "v0"),
    ({"v0": [None] * 6}, TypeError, "v0"),
]


BAD_OPTIONS += [
    ({"x0": [[0.0], [1.0, 2.0], [0.0], [0.0], [0.0], [0.0]]}, ArgumentError, re.escape("options['x0']")),
    ({"v0": [0.0, [1.0, 2.0], 0, 0, 0, 0]}, ArgumentError, re.escape("options['v0']")),
]


@pytest.mark.parametrize(("options", "error", "name"), BAD_OPTIONS)
def test_bad_reset_options_raise_naming_the_argument_and_leave_the_env_as_it_was(options, error, name):
    (env, twin), (obs, _), policy = started_pair(scenario="paper_fig1")
    with pytest.raises(error, match=name):
        env.reset(seed=99, options=options)
    assert_untouched_and_in_step(env, twin, obs, policy)


@pytest.mark.parametrize("seed", ["abc", -1, 1.5, True, 2**128, np.float64(3.0), [1, 2]])
def test_bad_seeds_raise_naming_seed_and_leave_the_env_as_it_was(seed):
    (env, twin), (obs, _), policy = started_pair(scenario="random_20_planar")
    with pytest.raises(ArgumentError, match="seed"):
        env.reset(seed=seed)
    with pytest.raises(ArgumentError, match="seed"):
        env.reset(seed=seed, options={"x0": np.zeros((20, 2))})
    assert_untouched_and_in_step(env, twin, obs, policy)


def test_numpy_integer_seeds_are_accepted():
    env, twin = fxc_env.parallel_env(), fxc_env.parallel_env()
    env.reset(seed=np.int64(5))
    twin.reset(seed=5)
    np.testing.assert_array_equal(env.state(), twin.state())


def test_reset_options_must_be_a_mapping():
    (env, twin), (obs, _), policy = started_pair()
    with pytest.raises(TypeError, match="options"):
        env.reset(options=[("x0", np.zeros(6))])
    assert_untouched_and_in_step(env, twin, obs, policy)


def test_bad_x0_shape_in_the_plane():
    env = fxc_env.parallel_env(topology="ring", n_agents=4, dim=2)
    with pytest.raises(ValueError, match=re.escape("(4, 2)")):
        env.reset(options={"x0": np.zeros(4)})


def test_step_after_the_episode_ended():
    env = fxc_env.parallel_env(scenario="paper_fig1", n_intervals=4)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    while env.agents:
        obs, *_ = env.step(reference_actions(policy, obs))
    state = env.state()
    with pytest.raises(RuntimeError, match="step"):
        env.step(reference_actions(policy, obs))
    np.testing.assert_array_equal(env.state(), state)
    # reset brings it back.
    obs, _ = env.reset(seed=0)
    env.step(reference_actions(policy, obs))


def test_step_before_reset():
    env = fxc_env.parallel_env()
    with pytest.raises(RuntimeError, match="reset"):
        env.step({f"agent_{i}": np.zeros(2) for i in range(6)})


BAD_CONSTRUCTION = [
    ({"topology": [(0, 1), (1, 2)], "n_agents": 4}, ValueError, r"topology.*agents \[3\]"),
    ({"topology": [[(0, 1)], [(2, 3)]], "n_agents": 4}, ValueError, r"topology.*union.*agents \[2, 3\]"),
    ({"topology": [(0, 1), (1, 2), (2, 2)]}, ValueError, r"topology.*self-loop"),
    ({"topology": [(0, 1), (1, 5)], "n_agents": 4}, ValueError, r"topology.*outside"),
    ({"topology": [(0, 1), (1, 2), (0, 1)]}, ValueError, r"topology.*more than once"),
    ({"topology": "hypercube"}, ValueError, "topology"),
    ({"settling_time": 0.0}, ValueError, "settling_time"),
    ({"settling_time": -20.0}, ValueError, "settling_time"),
    ({"settling_time": float("nan")}, ValueError, "settling_time"),
    ({"settling_time": float("inf")}, ValueError, "settling_time"),
    ({"n_intervals": 0}, ValueError, "n_intervals"),
    ({"n_intervals": -5}, ValueError, "n_intervals"),
    ({"n_agents": 0, "topology": "ring"}, ValueError, "n_agents"),
    ({"dim": 0}, ValueError, "dim"),
    ({"action_mode": "torque"}, ValueError, "action_mode"),
    ({"obs_mode": "absolute"}, ValueError, "obs_mode"),
    ({"obs_format": "tuple"}, ValueError, "obs_format"),
    ({"render_mode": "ansi"}, ValueError, "render_mode"),
    ({"max_cycles": 0}, ValueError, "max_cycles"),
    ({"initial_state": (np.zeros(5), np.zeros(6))}, ValueError, "x0"),
    ({"scenario": "paper_fig9"}, ValueError, "scenario"),
    ({"unknown_option": 1}, TypeError, "unknown_option"),
    ({"u_max": 0.0}, ValueError, "u_max"),
    ({"u_max": float("nan")}, ValueError, "u_max"),
    ({"obs_noise": -0.1}, ValueError, "obs_noise"),
    ({"link_dropout": 1.0}, ValueError, "link_dropout"),
    ({"link_dropout": -0.5}, ValueError, "link_dropout"),
    ({"switching": "markov"}, ValueError, "switching"),
    ({"obs_dtype": "float16"}, ValueError, "obs_dtype"),
    ({"obs_dtype": np.float32}, ValueError, "obs_dtype"),
    ({"global_state": "flat"}, ValueError, "global_state"),
    ({"topology": "complete", "obs_slots": 2}, ValueError, "obs_slots"),
    ({"initial_state": "zeros"}, ValueError, "initial_state"),
    ({"schedule": [10.0, 5.0]}, ValueError, "schedule"),
    ({"schedule": "geometric"}, ValueError, "schedule"),
]


@pytest.mark.parametrize(("kwargs", "error", "pattern"), BAD_CONSTRUCTION)
def test_bad_construction_names_the_argument_and_leaves_live_envs_alone(kwargs, error, pattern):
    (env, twin), (obs, _), policy = started_pair(scenario="paper_fig1")
    with pytest.raises(error, match=pattern):
        fxc_env.parallel_env(**kwargs)
    with pytest.raises(error, match=pattern):
        fxc_env.env(**kwargs)
    assert_untouched_and_in_step(env, twin, obs, policy)


def test_a_topology_family_and_a_set_of_input_limits_are_drawn_at_every_reset():
    from fxc_env.core.families import edge_lists

    family = {"family": "random", "mean_in_degree": (1.0, 3.0), "period": (1, 3)}
    env = fxc_env.parallel_env(topology=family, n_agents=8, n_intervals=5, u_max=(10.0, 100.0))
    topologies, limits = set(), set()
    for seed in range(8):
        obs, _ = env.reset(seed=seed)
        topologies.add(repr(edge_lists(env.engine.topologies[0])))
        limits.add(float(env.engine.u_max[0]))
        assert all(env.observation_space(agent).contains(o) for agent, o in obs.items())
    assert len(topologies) > 1 and limits == {10.0, 100.0}
    env.reset(seed=3)
    first = (repr(edge_lists(env.engine.topologies[0])), env.state().copy())
    env.reset(seed=3)
    assert first[0] == repr(edge_lists(env.engine.topologies[0])) and np.array_equal(first[1], env.state())


@pytest.mark.parametrize("switching", ["random", "periodic"])
def test_seed_tests_pass_and_no_info_is_nan(switching):
    """Two identically seeded runs give equal infos: NaN (never equal to itself) is never in them."""
    from pettingzoo.test import parallel_seed_test, seed_test

    kwargs = {"n_intervals": 6, "switching": switching}
    parallel_seed_test(lambda: fxc_env.parallel_env(**kwargs))
    seed_test(lambda: fxc_env.env(**kwargs), num_cycles=20)
    env = fxc_env.parallel_env(**kwargs)
    env.reset(seed=3)
    seen = []
    while env.agents:
        _, _, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
        for info in infos.values():
            seen += [v for v in info.values() if isinstance(v, float)]
            seen += [v for v in info.get("episode", {}).values()]
    assert seen and not any(math.isnan(v) for v in seen)


def test_random_box_actions_over_a_long_episode_are_refused_before_they_overflow_and_a_smaller_box_finishes():
    """The docs' "Exploring policies" (environment.md): at K = 2000 box-uniform actions with b = 2 overflow (refused,
    state unchanged, reset works); with ``action_bound=0.25`` the episode reaches T_s."""

    def play(**kwargs):
        env = fxc_env.parallel_env(scenario="paper_fig1", n_intervals=2000, **kwargs)
        env.reset(seed=0)
        space = env.action_space("agent_0")
        space.seed(0)
        steps = 0
        while env.agents:
            actions = {a: space.sample() for a in env.agents}
            before = env.state().copy()
            try:
                env.step(actions)
            except ValueError as error:
                assert str(error).startswith("actions:") and np.array_equal(env.state(), before)
                return env, steps
            steps += 1
        return env, steps

    env, steps = play()
    assert steps < 2000
    env.reset(seed=1)  # still usable
    assert np.isfinite(env.state()).all()
    _, steps = play(action_bound=0.25)
    assert steps == 2000
