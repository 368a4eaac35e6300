"""fxc_env.envs.interop: the environment inside TorchRL's PettingZooWrapper (one group, flat infos)."""

from __future__ import annotations

import math

import numpy as np
import torch
from pettingzoo.test import parallel_api_test
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import check_env_specs

import fxc_env
from fxc_env.envs.interop import EPISODE_KEYS, FlatEpisodeInfos, torchrl_wrapper

AGENTS = [f"agent_{i}" for i in range(6)]


def test_torchrl_wrapper_passes_check_env_specs_with_all_agents_in_one_group():
    env = torchrl_wrapper(scenario="paper_fig1")
    check_env_specs(env)
    assert env.group_map == {"agents": AGENTS}
    obs_size = fxc_env.make_config("paper_fig1").layout.size
    assert env.observation_spec["agents", "observation"].shape == (6, obs_size)
    action = env.full_action_spec["agents", "action"]
    assert action.shape == (6, 2) and action.dtype == torch.float64
    assert torch.all(action.space.high == 2.0)  # plan mode, normalized: the Box of the env card
    assert env.observation_spec["state"].shape == (6, 2)
    assert set(env.observation_spec["agents", "info"].keys()) >= {"t", "interval", "energy", *EPISODE_KEYS}


def test_the_reference_through_torchrl_reaches_the_deadline_with_the_episode_metrics_of_the_plain_env():
    env = torchrl_wrapper(scenario="paper_fig1")  # the paper's initial state: no seed needed
    reference = fxc_env.ReferencePolicy(fxc_env.make_config("paper_fig1"))
    policy = TensorDictModule(
        lambda obs: torch.as_tensor(reference(obs.numpy())),
        in_keys=[("agents", "observation")],
        out_keys=[("agents", "action")],
    )
    rollout = env.rollout(1000, policy=policy, break_when_any_done=True)
    assert rollout.batch_size == (200,)  # K = 200 steps, then the deadline ends the episode
    done = rollout["next", "done"].squeeze(-1)
    assert done[-1] and not done[:-1].any()

    plain = fxc_env.parallel_env(scenario="paper_fig1")
    observations, _ = plain.reset()
    while plain.agents:
        observations, _, _, _, infos = plain.step({a: reference(o) for a, o in observations.items()})
    episode = infos["agent_0"]["episode"]

    info = rollout["next", "agents", "info"]
    assert torch.isnan(info["episode_relative_deadline_error"][:-1]).all()  # only the last step carries them
    for key in EPISODE_KEYS:
        expected = episode.get(key.removeprefix("episode_"))  # a NaN metric (a floor off) is left out
        expected = math.nan if expected is None else float(expected)
        np.testing.assert_allclose(info[key][-1].double().numpy(), expected, rtol=1e-6, err_msg=key)
    assert float(info["episode_relative_deadline_error"][-1, 0]) < 1e-11  # the paper's example: 2.9e-12
    total = rollout["next", "agents", "reward"].sum(0).squeeze(-1)
    assert torch.allclose(total, total[0]) and float(total[0]) > 20  # team reward, ln D(0)/D(T_s)


def test_flat_infos_keep_one_schema_and_the_pettingzoo_api():
    env = FlatEpisodeInfos(fxc_env.parallel_env(scenario="ring_6", n_intervals=5))
    _, reset_infos = env.reset(seed=0)
    keys = set(reset_infos["agent_0"])
    assert "episode" not in keys and set(EPISODE_KEYS) <= keys
    while env.agents:
        _, _, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
        assert all(set(info) == keys for info in infos.values())
    assert np.isfinite(infos["agent_0"]["episode_relative_deadline_error"])
    assert infos["agent_0"]["episode_sampling_instants"] == 5.0
    assert env.metadata["name"] == "fxc_consensus_v0"
    parallel_api_test(FlatEpisodeInfos(fxc_env.parallel_env(scenario="ring_6", n_intervals=10)), num_cycles=15)
