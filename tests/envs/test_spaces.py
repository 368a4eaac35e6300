"""fxc_env.envs.spaces: the spaces are shared by both front ends and hold what the env emits."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import MODES_DEFAULT_FAST

import fxc_env
from fxc_env.config import make_config
from fxc_env.engine import ConsensusEngine
from fxc_env.envs.spaces import action_space, observation_space, state_space


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES_DEFAULT_FAST)
def test_reference_actions_fit_the_action_box_in_normalized_mode_for_any_state(action_mode, obs_mode):
    """The action Box is wide enough for the reference (eq. 11); in normalised units for every state."""
    config = make_config(
        topology="random",
        n_agents=12,
        topology_period=2,
        mean_in_degree=3.0,
        action_mode=action_mode,
        obs_mode=obs_mode,
    )
    engine = ConsensusEngine(config, n_episodes=64)
    rng = np.random.default_rng(5)
    # Initial states over many orders of magnitude; raw mode only for the documented ranges.
    scale = 10.0 ** rng.uniform(-6, 6, size=(64, 1, 1)) if obs_mode == "normalized" else 1.0
    x0 = scale * rng.uniform(-5, 5, size=(64, 12, 1))
    v0 = scale * rng.uniform(-2, 2, size=(64, 12, 1))
    engine.reset(x0, v0)
    policy = fxc_env.ReferencePolicy(config)
    box = action_space(config)
    obs_box = observation_space(config)
    while not engine.done:
        obs = engine.observations()
        assert all(obs_box.contains(row) for row in obs.reshape(-1, obs.shape[-1])[::37])
        actions = policy(obs)
        assert np.all(actions >= box.low) and np.all(actions <= box.high)
        engine.step(actions)


def test_parallel_env_and_vec_env_expose_the_same_spaces():
    env = fxc_env.parallel_env(scenario="random_20_planar", obs_mode="raw")
    venv = fxc_env.ConsensusVecEnv(2, scenario="random_20_planar", obs_mode="raw")
    agent = env.possible_agents[0]
    assert env.observation_space(agent) == venv.observation_space
    assert env.action_space(agent) == venv.action_space
    assert env.state_space == state_space(env.config)
    assert env.state_space.shape == (20, 4)


def test_dict_form_holds_rows_mask_and_clock():
    config = make_config("paper_fig1", obs_format="dict")
    space = observation_space(config)
    assert set(space.spaces) == {"neighbours", "mask", "clock"}
    assert space["neighbours"].shape == (config.layout.slots, 2 * config.dim)
    assert space["clock"].shape == (3,)


@pytest.mark.parametrize("obs_format", ["flat", "dict"])
@pytest.mark.parametrize("obs_mode", ["normalized", "raw"])
def test_float32_spaces_have_the_float64_bounds(obs_format, obs_mode):
    wide = observation_space(make_config("random_20_planar", obs_format=obs_format, obs_mode=obs_mode))
    narrow = observation_space(
        make_config("random_20_planar", obs_format=obs_format, obs_mode=obs_mode, obs_dtype="float32")
    )
    pairs = zip(wide.spaces.values(), narrow.spaces.values(), strict=True) if obs_format == "dict" else [(wide, narrow)]
    for w, n in pairs:
        assert w.dtype == np.float64 and n.dtype == np.float32
        np.testing.assert_array_equal(w.low, n.low)
        np.testing.assert_array_equal(w.high, n.high)


def test_state_space_follows_global_state_and_obs_dtype():
    raw = state_space(make_config("random_20_planar", obs_dtype="float32"))
    assert raw.shape == (20, 4) and raw.dtype == np.float64  # the raw state is physical, float64
    normalized = state_space(make_config("random_20_planar", global_state="normalized", obs_dtype="float32"))
    assert normalized.shape == (20 * 4 + 3,) and normalized.dtype == np.float32
    assert normalized.is_bounded() and np.all(normalized.low[:-3] == -1) and np.all(normalized.low[-3:] == 0)


@pytest.mark.parametrize("obs_format", ["flat", "dict"])
def test_an_input_limit_adds_one_bounded_entry(obs_format):
    config = make_config("paper_fig1", u_max=100.0, obs_format=obs_format)
    env = fxc_env.parallel_env("paper_fig1", u_max=100.0, obs_format=obs_format)
    space = observation_space(config)
    obs, _ = env.reset(seed=0)
    assert space.contains(obs["agent_0"])
    if obs_format == "dict":
        assert space["input_limit"].shape == (1,) and set(obs["agent_0"]) == set(space.spaces)
    else:
        assert space.shape == (config.layout.size,) and space.low[-1] == -1 and space.high[-1] == 1
