"""Real clients, driven as their documentation shows: SuperSuit into stable-baselines3, and TorchRL.

(RLlib's ``ParallelPettingZooEnv`` runs in its own environment: tests/rllib.)
"""

from __future__ import annotations

import numpy as np
import pytest
import supersuit as ss
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector

import fxc_env
from fxc_env.envs.interop import torchrl_wrapper

K = 16


def supersuit_vec_env(n_copies: int = 2):
    """PettingZoo's recipe for SB3: every agent a sub-environment, ``n_copies`` pickled copies of the env."""
    env = fxc_env.parallel_env(n_intervals=K)  # the default topology with random initial states
    venv = ss.pettingzoo_env_to_vec_env_v1(env)
    return ss.concat_vec_envs_v1(venv, n_copies, num_cpus=0, base_class="stable_baselines3")


def test_supersuit_copies_draw_independent_episodes():
    venv = supersuit_vec_env(3)
    n = 6
    assert venv.num_envs == 3 * n
    first = venv.reset()
    copies = first.reshape(3, n, -1)
    assert not np.array_equal(copies[0], copies[1]) and not np.array_equal(copies[1], copies[2])
    second = venv.reset()  # unseeded: each copy continues its own generator
    assert not np.array_equal(first, second)


@pytest.mark.slow
def test_ppo_trains_a_few_hundred_steps_through_supersuit():
    venv = VecMonitor(supersuit_vec_env(2))
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=96, n_epochs=1, device="cpu")
    model.learn(total_timesteps=384)
    assert model.num_timesteps >= 384
    assert {info["l"] for info in model.ep_info_buffer} == {K}  # whole episodes, ended at the deadline
    obs = venv.reset()
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (venv.num_envs, 2)
    _, _, _, infos = venv.step(actions)
    assert all(isinstance(info, dict) for info in infos)


@pytest.mark.slow
def test_torchrl_collector_with_a_float32_policy():
    env = torchrl_wrapper(scenario="paper_fig1", n_intervals=K, obs_dtype="float32", global_state="normalized")
    observation = env.observation_spec["agents", "observation"]
    assert observation.dtype == torch.float32 and env.observation_spec["state"].dtype == torch.float32
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(observation.shape[-1], 32), torch.nn.Tanh(), torch.nn.Linear(32, 2))
    policy = TensorDictModule(net, in_keys=[("agents", "observation")], out_keys=[("agents", "action")])
    collector = Collector(env, policy, frames_per_batch=12, total_frames=36, auto_register_policy_transforms=False)
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 3
    for batch in batches:
        assert batch["agents", "observation"].dtype == torch.float32
        assert batch["agents", "observation"].shape == (12, 6, observation.shape[-1])
        assert batch["state"].shape == (12, 6 * 2 + 3)
        assert torch.isfinite(batch["next", "agents", "reward"]).all()
    done = torch.cat([batch["next", "done"].flatten() for batch in batches])
    assert done.sum() == 2  # K = 16 steps per episode: 36 frames hold two episode ends
