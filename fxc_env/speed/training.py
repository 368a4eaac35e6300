"""Training throughput: PPO end to end per back end on ``paper_fig1`` (SB3, the torch back end, TorchRL's pieces).

Each back end trains whole PPO rollouts in a scratch directory (set-up, collection, updates
and logging timed together). It trains, so it runs only when selected (``--only training``)
or in the full default run, never with ``--skip-contenders``.
"""

from __future__ import annotations

import os
import time
from typing import Any

from fxc_env.speed.timing import importable, met

#: Agent-steps each back end trains for in the training table (whole PPO rollouts on paper_fig1).
TRAINING_TIMESTEPS = {"sb3": 2 * 16 * 6 * 200, "torch": 8 * 64 * 6 * 200}

#: The torch back end's goal: agent-steps per second of PPO (collection and updates) on the CPU.
TRAINING_GOAL = 1e5


def training_rate(backend: str, timesteps: int, threads: int) -> tuple[float, float]:
    """(agent-steps/s over the run, wall seconds) of ``fxc train --backend`` on paper_fig1, PPO, in a scratch directory."""
    import contextlib
    import io
    import tempfile

    from fxc_env.training.args import TrainArgs
    from fxc_env.training.backends import train

    with tempfile.TemporaryDirectory() as scratch, contextlib.redirect_stdout(io.StringIO()):
        start = time.perf_counter()
        args = TrainArgs(
            scenario="paper_fig1",
            backend=backend,
            timesteps=timesteps,
            run_dir=scratch,
            progress_bar=False,
            torch_threads=threads,
            checkpoint_every=10**9,
        )
        train(args)
        seconds = time.perf_counter() - start
    return timesteps / seconds, seconds


def _torchrl_ppo(size: int, actions: int, bound: float) -> tuple[Any, Any]:
    """TorchRL's TanhNormal actor and ``ClipPPOLoss`` (GAE, gamma 1, lambda 0.95) with 64 x 64 tanh networks."""
    import torch
    from tensordict.nn import TensorDictModule
    from torch import nn
    from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    from fxc_env.envs.torch_env import GROUP
    from fxc_env.policies.networks import mlp

    class Gaussian(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mean = mlp(size, actions, (64, 64))
            self.log_std = nn.Parameter(torch.full((actions,), -2.0))

        def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            loc = self.mean(observation)
            return loc, torch.exp(self.log_std).expand_as(loc)

    keys = [(GROUP, "loc"), (GROUP, "scale")]
    actor = ProbabilisticActor(
        TensorDictModule(Gaussian(), in_keys=[(GROUP, "observation")], out_keys=keys),
        in_keys=keys,
        out_keys=[(GROUP, "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -bound, "high": bound},
        return_log_prob=True,
        log_prob_key=(GROUP, "sample_log_prob"),
    )
    critic = ValueOperator(mlp(size, 1, (64, 64)), in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "state_value")])
    loss = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=0.2, entropy_coeff=0.0)
    loss.set_keys(
        reward=(GROUP, "reward"),
        action=(GROUP, "action"),
        sample_log_prob=(GROUP, "sample_log_prob"),
        value=(GROUP, "state_value"),
        done=(GROUP, "done"),
        terminated=(GROUP, "terminated"),
    )
    loss.make_value_estimator(ValueEstimators.GAE, gamma=1.0, lmbda=0.95)
    return actor, loss


def torchrl_collector_rate(rollouts: int = 3, episodes: int = 64, epochs: int = 2, minibatch: int = 2048) -> float:
    """Agent-steps/s of PPO written with TorchRL's own pieces on :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv`.

    ``Collector`` + ``ClipPPOLoss`` (GAE, a replay buffer of one rollout, TanhNormal actor)
    with the torch back end's settings on paper_fig1 (B = ``episodes``, one whole episode a
    rollout, ``epochs`` passes in minibatches of ``minibatch`` agent-steps, 64 x 64 tanh
    networks): the alternative ``--backend torch`` was measured against. The first
    rollout (warm-up) is not timed.
    """
    import torch
    from torch import nn
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, ReplayBuffer
    from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement

    from fxc_env.envs.torch_env import GROUP, ConsensusTorchEnv

    env = ConsensusTorchEnv(
        batch_size=episodes, seed=0, obs_dtype="float32", scenario="paper_fig1", obs_slots=4, initial_state="random"
    )
    actor, loss = _torchrl_ppo(env.config.layout.size, env.config.action_size, env.config.action_bound)
    frames = episodes * env.config.n_intervals
    collector = Collector(
        env,
        actor,
        frames_per_batch=frames,
        total_frames=frames * (rollouts + 1),
        device="cpu",
        auto_register_policy_transforms=False,
    )
    optimiser = torch.optim.Adam(loss.parameters(), lr=3e-4, eps=1e-5)
    per_minibatch = max(1, minibatch // env.n_agents)
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(frames), sampler=SamplerWithoutReplacement(), batch_size=per_minibatch
    )
    seconds, start = 0.0, time.perf_counter()
    for index, data in enumerate(collector):
        for key in ("done", "terminated"):  # the group's per-agent flags, from the episode's
            shape = data.get_item_shape(("next", GROUP, "reward"))
            data.set(("next", GROUP, key), data.get(("next", key)).unsqueeze(-1).expand(shape))
        with torch.no_grad():
            loss.value_estimator(
                data, params=loss.critic_network_params, target_params=loss.target_critic_network_params
            )
        buffer.extend(data.reshape(-1))
        for _ in range(epochs * (frames // per_minibatch)):
            values = loss(buffer.sample())
            total = values["loss_objective"] + values["loss_critic"] + values["loss_entropy"]
            optimiser.zero_grad()
            total.backward()
            nn.utils.clip_grad_norm_(loss.parameters(), 0.5)
            optimiser.step()
        collector.update_policy_weights_()
        if index:
            seconds += time.perf_counter() - start
        start = time.perf_counter()
    collector.shutdown()
    return rollouts * frames * env.n_agents / seconds


def training_table(threads: int | None = None) -> list[str]:
    """PPO's throughput, end to end (collection, updates, logging; set-up included), per back end on paper_fig1.

    SB3 on :class:`~fxc_env.envs.vec_env.ConsensusVecEnv` and the torch back end on the torch
    engine, each with ``threads`` torch threads (default: every core); RLlib needs Ray, which
    lives in ``.venv-rllib`` (``fxc train --backend rllib`` prints its own rate there).
    """
    import torch

    threads = threads or os.cpu_count() or 1
    previous = torch.get_num_threads()
    lines = ["| back end | agent-steps | wall (s) | agent-steps/s | vs SB3 |", "|---|---:|---:|---:|---:|"]
    rates = {}
    try:
        for backend, timesteps in TRAINING_TIMESTEPS.items():
            rates[backend], seconds = training_rate(backend, timesteps, threads)
            lines.append(
                f"| {backend} | {timesteps:,} | {seconds:.1f} | {rates[backend]:,.0f} | {rates[backend] / rates['sb3']:.1f}x |"
            )
    finally:
        torch.set_num_threads(previous)
    if importable("torchrl"):
        torch.set_num_threads(threads)
        rate = torchrl_collector_rate()
        torch.set_num_threads(previous)
        lines.append(
            f"| TorchRL Collector + ClipPPOLoss on ConsensusTorchEnv (same settings, not shipped) | 3 rollouts | | "
            f"{rate:,.0f} | {rate / rates['sb3']:.1f}x |"
        )
    if importable("ray"):
        lines.append("| rllib | | | (run `fxc train --backend rllib`: it prints its rate) | |")
    else:
        lines.append("| rllib | | | not in this environment (Ray lives in .venv-rllib) | |")
    rate = rates["torch"]
    lines += [
        "",
        f"torch back end: {rate:,.0f} agent-steps/s with {threads} threads "
        f"(goal >= {TRAINING_GOAL:,.0f}: {met(rate >= TRAINING_GOAL)})",
    ]
    return lines
