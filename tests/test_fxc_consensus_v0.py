"""PettingZoo compliance (SPEC 1, 4.1): the official API tests over every scenario and mode."""

from __future__ import annotations

import functools
import types
import warnings

import numpy as np
import pytest
from helpers import ACTION_MODES, MODES, OBS_MODES
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, render_test, state_test

import fxc_env
from fxc_env import fxc_consensus_v0

SCENARIO_NAMES = sorted(fxc_env.SCENARIOS)
#: K for the API runs: long enough to reach the deadline inside the test's cycles, and fast.
K = 40

ALL = [
    pytest.param(scenario, action_mode, obs_mode, id=f"{scenario}-{action_mode}-{obs_mode}")
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
    assert fxc_env.raw_env is fxc_consensus_v0.raw_env
    assert isinstance(fxc_consensus_v0.raw_env(), ParallelEnv)
    assert fxc_env.parallel_env().metadata["name"] == "fxc_consensus_v0"


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


@pytest.mark.parametrize("scenario", SCENARIO_NAMES)
@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
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
    # SPEC 4.1 defaults (K = 200), once, through the whole episode.
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


@pytest.mark.parametrize(("scenario", "action_mode", "obs_mode"), ALL)
def test_max_cycles(scenario, action_mode, obs_mode):
    max_cycles_test(_module_with(scenario=scenario, action_mode=action_mode, obs_mode=obs_mode))


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

    from fxc_env.consensus_env import ConsensusParallelEnv

    parallel = pettingzoo.make("parallel", "fxc_consensus_v0", scenario="paper_fig1")
    assert isinstance(parallel, ConsensusParallelEnv)
    assert parallel.metadata["name"] == "fxc_consensus_v0" == fxc_env.ENV_ID
    aec = pettingzoo.make("aec", "fxc_consensus_v0", n_intervals=5)
    assert isinstance(aec.unwrapped, ConsensusParallelEnv) and aec.unwrapped.config.n_intervals == 5
    aec.reset(seed=0)
    assert aec.agent_selection == "agent_0"
