"""Real clients, driven as their documentation shows: SuperSuit into stable-baselines3, TorchRL and Tianshou.

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


def tianshou_ippo(monkeypatch, **settings):
    """Tianshou's multi-agent route for PettingZoo: its ``PettingZooEnv`` over the AEC form, one PPO per agent (IPPO).

    One short training epoch (two environments, 96 agent steps), then 48 more steps collected with
    the trained policies (on-policy training empties the buffer after each update); returns the
    collector.
    Tianshou 2.0.1's ``MultiAgentPolicy.forward`` reads ``batch.obs_next`` unconditionally, and the
    collector's action batch has none (``AttributeError: 'dict' object has no attribute
    'obs_next'`` on the first step, whatever the environment). The one-line fix is theirs (guard
    ``if hasattr(tmp_batch.obs_next, "obs")`` with ``"obs_next" in tmp_batch.get_keys()``); here the
    same effect by handing ``forward`` an empty ``obs_next`` (docs: environment.md, "The environment").
    """
    import tianshou as ts  # installed by make test (the [tianshou] extra)
    from tianshou.algorithm import PPO
    from tianshou.algorithm.modelfree.reinforce import ProbabilisticActorPolicy
    from tianshou.algorithm.multiagent.marl import MultiAgentOnPolicyAlgorithm, MultiAgentPolicy
    from tianshou.algorithm.optim import AdamOptimizerFactory
    from tianshou.data import Batch, Collector, VectorReplayBuffer
    from tianshou.env import DummyVectorEnv, PettingZooEnv
    from tianshou.trainer import OnPolicyTrainerParams
    from tianshou.utils.net.common import Net
    from tianshou.utils.net.continuous import ContinuousActorProbabilistic, ContinuousCritic

    assert ts.__version__ == "2.0.1"  # the release whose obs_next bug the patch below works around
    forward = MultiAgentPolicy.forward

    def patched(self, batch, state=None, **kwargs):
        if "obs_next" not in batch.get_keys():
            batch.obs_next = Batch()
        return forward(self, batch, state, **kwargs)

    monkeypatch.setattr(MultiAgentPolicy, "forward", patched)

    def make():
        return PettingZooEnv(fxc_env.env(n_intervals=6, obs_dtype="float32", **settings))

    env = make()
    size = env.observation_space.shape[0]

    def ppo():
        actor = ContinuousActorProbabilistic(
            preprocess_net=Net(state_shape=size, hidden_sizes=[16]), action_shape=env.action_space.shape, unbounded=True
        )
        policy = ProbabilisticActorPolicy(
            actor=actor,
            dist_fn=lambda loc_scale: torch.distributions.Independent(torch.distributions.Normal(*loc_scale), 1),
            action_space=env.action_space,
            action_scaling=False,
            action_bound_method=None,
        )
        critic = ContinuousCritic(preprocess_net=Net(state_shape=size, hidden_sizes=[16]))
        return PPO(policy=policy, critic=critic, optim=AdamOptimizerFactory(lr=1e-3))

    torch.manual_seed(0)
    algorithm = MultiAgentOnPolicyAlgorithm(algorithms=[ppo() for _ in env.agents], env=env)
    collector = Collector(algorithm, DummyVectorEnv([make, make]), VectorReplayBuffer(200, 2))
    collector.reset(gym_reset_kwargs={"seed": 0})
    algorithm.run_training(
        OnPolicyTrainerParams(
            training_collector=collector,
            max_epochs=1,
            epoch_num_steps=96,
            collection_step_num_env_steps=96,
            batch_size=32,
            show_progress=False,
        )
    )
    collector.collect(n_step=48)
    return collector


@pytest.mark.parametrize(
    "settings",
    [
        {"scenario": "generalist", "n_agents": 4},
        {"scenario": "generalist", "n_agents": 4, "graph_tensors": True, "u_max": (2.0, 5.0)},
    ],
    ids=["family", "family_graph_tensors_u_max"],
)
@pytest.mark.slow
def test_tianshou_ippo_trains_on_a_topology_family_and_with_graph_tensors(monkeypatch, settings):
    """Tianshou stores every info key in its buffer: one type and shape at reset and every step, no NaN."""
    collector = tianshou_ippo(monkeypatch, **settings)
    buffer = collector.buffer
    assert len(buffer) >= 48 and not buffer.hasnull()  # what Tianshou checks (MalformedBufferError)
    info = buffer.info[: len(buffer)]
    assert "edges" not in info.get_keys()
    if settings.get("graph_tensors"):
        width = 4 * fxc_env.parallel_env(**settings).config.layout.slots  # N slots for a family
        assert info.edge_index.shape == (len(buffer), 2, width) and info.edge_mask.shape == (len(buffer), width)
        assert ((info.edge_index < 4) == info.edge_mask[:, None]).all()  # padding is the extra node N = 4
        assert set(np.unique(info.u_max)) <= {2.0, 5.0}
