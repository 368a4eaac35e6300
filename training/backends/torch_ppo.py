"""``fxc train --backend torch``: a lean PPO loop on the batched engine, on a torch device.

One Gaussian policy shared by every agent of B parallel episodes (IPPO with parameter sharing) on
:class:`fxc_env.engine.ConsensusEngine` (float64 on ``--device``; float32 networks); nothing is read back to
the host on the stepping path. The critic is ``local`` or ``central`` (one value per episode from the
normalized global state). The loop is SB3's PPO written out for the engine's tensors, its settings the
``torch_ppo`` entry of the hyperparameter file (:class:`PPOSettings`):

    rollout:  T steps of B episodes (T divides K; an episode is K steps), B * N agent-steps each
    update:   ``epochs`` passes over the T * B * N agent-steps in minibatches of ``minibatch_size``

``progress.csv`` has one row per rollout (:data:`PROGRESS_COLUMNS`); checkpoints and ``--resume`` are
:mod:`fxc_env.training.backends.torch_common`'s (docs: training.md, "Training learned policies").
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from fxc_env.config import make_config
from fxc_env.engine import ConsensusEngine
from fxc_env.engine.graph_tensors import edge_capacity
from fxc_env.policies.torch_memory import interval_graph
from fxc_env.training.args import TrainArgs, env_label
from fxc_env.training.backends.torch_common import (  # noqa: F401
    ActorCritic,
    TrainerFiles,
    adam,
    drive,
    init_actor,
    latest_torch_checkpoint,
    prepare,
    run_config,
)
from fxc_env.training.settings import PPOSettings

#: Columns of ``progress.csv`` (SB3's names where they mean the same, so one curve plotter serves all).
PROGRESS_COLUMNS = (
    "time/iterations",
    "time/total_timesteps",
    "time/fps",
    "time/time_elapsed",
    "time/collect_seconds",
    "time/update_seconds",
    "rollout/ep_rew_mean",
    "rollout/deadline_error",
    "rollout/episodes",
    "train/policy_loss",
    "train/value_loss",
    "train/entropy_loss",
    "train/approx_kl",
    "train/clip_fraction",
    "train/explained_variance",
    "train/std",
    "train/learning_rate",
    "train/n_updates",
)


# ---------------------------------------------------------------------------------- training
class Trainer(TrainerFiles):
    """The state of one run: engine, networks, optimiser, generators, counters and buffers."""

    def __init__(self, args: TrainArgs, params: dict[str, Any], settings: PPOSettings, device: torch.device) -> None:
        self.args, self.settings, self.device = args, settings, device
        self.env_kwargs = run_config(args, params)
        self.config = config = make_config(**self.env_kwargs)
        self.n_envs = int(args.n_envs or settings.n_envs)
        self.n_agents = config.n_agents
        self.obs_size = config.layout.size
        self.action_size = config.action_size
        self.bound = float(config.action_bound)
        self.central = args.critic == "central"
        self.engine = ConsensusEngine(config, self.n_envs, device=device)
        self.engine.seed(args.seed)
        self.host_rng = np.random.default_rng(args.seed)  # topology families only
        self.generator = torch.Generator(device=device)  # exploration noise and minibatch order
        self.generator.manual_seed(int(np.random.SeedSequence([args.seed, 1]).generate_state(1)[0]))
        self.episode_return = torch.zeros(self.n_envs, dtype=torch.float64, device=device)
        torch.manual_seed(args.seed)  # the networks' initial weights
        self._reset()
        self.state_size = self.engine.normalized_state().shape[-1] if self.central else self.obs_size
        self.arch = args.policy_arch
        self.clock_index = config.layout.clock_end - 1  # k/K
        self.rows_end = config.layout.rows_end
        self.model = ActorCritic(
            self.obs_size, self.action_size, self.state_size, settings, self.arch, self.clock_index, self.rows_end
        ).to(device)
        self.optimizer = adam(self.model.parameters(), settings.learning_rate)
        self.timesteps = 0
        self.iterations = 0
        self.n_updates = 0
        if args.init_from is not None:
            init_actor(self, args.init_from)
        self.fresh = True  # the engine's episodes were just reset
        t, b, n = settings.rollout_steps, self.n_envs, self.n_agents
        f32 = dict(dtype=torch.float32, device=device)
        self.obs = torch.empty((t, b, n, self.obs_size), **f32)
        self.actions = torch.empty((t, b, n, self.action_size), **f32)
        self.log_probs = torch.empty((t, b, n), **f32)
        self.rewards = torch.empty((t, b), **f32)
        self.states = torch.empty((t, b, self.state_size), **f32) if self.central else None
        if self.arch == "gru":  # the memory when the rollout began, [B, N, gru_size], and as it goes on
            self.hidden = self.model.actor.initial_state((b, n), device)
            self.start_hidden = self.hidden.clone()
        if self.arch == "gnn":  # each step's interval graph as edge tensors, padded to a fixed E
            self.edge_width = edge_capacity(config)
            self.edge_index = torch.empty((t, b, 2, self.edge_width), dtype=torch.int64, device=device)
            self.edge_mask = torch.empty((t, b, self.edge_width), dtype=torch.bool, device=device)

    # ---------------------------------------------------------------------- episodes
    def _reset(self) -> None:
        x0, v0, u_max, topologies = self.engine.draw_batch(self.host_rng)
        self.engine.reset(x0, v0, topologies=topologies, u_max=u_max)
        self.episode_return.zero_()
        self.fresh = True

    # ----------------------------------------------------------------------- rollout
    def collect(self) -> dict[str, Any]:
        """One rollout of T steps; returns the returns and deadline errors of the episodes that ended."""
        engine, model, bound = self.engine, self.model, self.bound
        std = torch.exp(model.log_std.detach())
        terminal = []
        finished_returns, finished_errors = [], []
        if not self.fresh and engine.done:
            self._reset()
        if self.arch == "gru":
            self.start_hidden = self.hidden.clone()
        with torch.no_grad():
            for t in range(self.settings.rollout_steps):
                obs = engine.observations().to(torch.float32)
                self.obs[t] = obs
                if self.central:
                    self.states[t] = engine.normalized_state().to(torch.float32)
                if self.arch == "gru":  # the memory resets where the clock reads k = 0 (an episode's start)
                    mean, self.hidden = model.actor.step(obs, self.hidden)
                elif self.arch == "gnn":
                    edge_index, edge_mask = interval_graph(engine, obs, self.edge_width)
                    self.edge_index[t], self.edge_mask[t] = edge_index, edge_mask
                    mean = model.actor(obs, edge_index, edge_mask)
                else:
                    mean = model.actor(obs)
                noise = torch.randn(mean.shape, generator=self.generator, dtype=mean.dtype, device=mean.device)
                actions = mean + std * noise
                self.actions[t] = actions
                self.log_probs[t] = model.log_prob(mean, actions)
                outcome = engine.step(engine.validate_actions(actions.clamp(-bound, bound)))
                self.rewards[t] = outcome.reward
                self.episode_return += outcome.reward
                self.fresh = False
                terminal.append(bool(outcome.terminated))
                if outcome.terminated:  # lock step: every episode ends here (one host read per episode)
                    engine.raise_if_invalid()
                    finished_returns.append(self.episode_return.clone())
                    finished_errors.append(engine.batch_metrics()["relative_deadline_error"])
                    if t + 1 < self.settings.rollout_steps:
                        self._reset()
            # The value after the last step: 0 at an episode end, else bootstrapped.
            last_value = None
            if not terminal[-1]:
                inputs = engine.normalized_state() if self.central else engine.observations()
                last_value = model.critic(inputs.to(torch.float32)).squeeze(-1)
        return {
            "terminal": terminal,
            "last_value": last_value,
            "returns": torch.cat(finished_returns) if finished_returns else None,
            "errors": np.concatenate(finished_errors) if finished_errors else None,
        }

    def advantages(self, rollout: dict[str, Any]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """GAE: advantages, value targets ``[T, B, N]`` (local) or ``[T, B]`` (central), and the explained variance."""
        s = self.settings
        with torch.no_grad():
            values = self.model.critic(self.states if self.central else self.obs).squeeze(-1)
            rewards = self.rewards if self.central else self.rewards[:, :, None]
            advantages = torch.empty_like(values)
            running = torch.zeros_like(values[0])
            next_value = rollout["last_value"]
            for t in reversed(range(s.rollout_steps)):
                if rollout["terminal"][t]:
                    delta = rewards[t] - values[t]
                    running = delta
                else:
                    delta = rewards[t] + s.gamma * next_value - values[t]
                    running = delta + (s.gamma * s.gae_lambda) * running
                advantages[t] = running
                next_value = values[t]
            targets = advantages + values
            explained = 1.0 - torch.var(advantages) / torch.var(targets)
        return advantages, targets, explained

    # ------------------------------------------------------------------------ update
    def update(self, advantages: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """``epochs`` passes of clipped-surrogate minibatch steps; returns the statistics (on the device)."""
        if self.arch == "gru":
            return self._update_sequences(advantages, targets)
        if self.arch == "gnn":
            return self._update_graphs(advantages, targets)
        s, model, n = self.settings, self.model, self.n_agents
        obs = self.obs.reshape(-1, self.obs_size)
        actions = self.actions.reshape(-1, self.action_size)
        old_log_probs = self.log_probs.reshape(-1)
        if self.central:
            # One value per episode and step; its agents share the episode's advantage.
            per_agent = advantages[:, :, None].expand(-1, -1, n).reshape(-1)
            states = self.states.reshape(-1, self.state_size)
        else:
            per_agent = advantages.reshape(-1)
        targets = targets.reshape(-1)
        total = obs.shape[0]

        def step(index: torch.Tensor) -> torch.Tensor:
            batch = obs[index]
            if self.central:
                value_index = torch.div(index, n, rounding_mode="floor")
                value, target = model.critic(states[value_index]).squeeze(-1), targets[value_index]
            else:
                value, target = model.critic(batch).squeeze(-1), targets[index]
            mean = model.actor(batch)
            return self._minibatch_step(mean, actions[index], old_log_probs[index], per_agent[index], value, target)

        return self._passes(total, s.minibatch_size, step)

    def _passes(self, total: int, size: int, step: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
        """``epochs`` passes over ``total`` items, each in a fresh order from the generator, ``size`` at a time:
        the mean of ``step(index)`` (a minibatch's five statistics, :meth:`_minibatch_step`) over the minibatches."""
        sums = torch.zeros(5, dtype=torch.float32, device=self.device)
        count = 0
        for _ in range(self.settings.epochs):
            order = torch.randperm(total, generator=self.generator, device=self.device)
            for first in range(0, total, size):
                sums += step(order[first : first + size])
                count += 1
        self.n_updates += count
        return sums / count

    def _minibatch_step(
        self,
        mean: torch.Tensor,
        actions: torch.Tensor,
        old_log_probs: torch.Tensor,
        advantage: torch.Tensor,
        value: torch.Tensor,
        target: torch.Tensor,
    ) -> torch.Tensor:
        """One clipped-surrogate gradient step on a minibatch (any matching shapes); its statistics."""
        s, model = self.settings, self.model
        if s.normalize_advantage and advantage.numel() > 1:
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        log_ratio = model.log_prob(mean, actions) - old_log_probs
        ratio = torch.exp(log_ratio)
        policy_loss = -torch.min(
            advantage * ratio, advantage * torch.clamp(ratio, 1.0 - s.clip_range, 1.0 + s.clip_range)
        ).mean()
        value_loss = torch.mean((value - target) ** 2)
        entropy = model.entropy()
        loss = policy_loss + s.vf_coef * value_loss - s.ent_coef * entropy
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), s.max_grad_norm)
        self.optimizer.step()
        with torch.no_grad():
            approx_kl = torch.mean((ratio - 1.0) - log_ratio)
            clipped = torch.mean((torch.abs(ratio - 1.0) > s.clip_range).to(torch.float32))
            return torch.stack([policy_loss, value_loss, -entropy, approx_kl, clipped]).detach()

    def _update_sequences(self, advantages: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """``gru``: minibatches of whole agent sequences, the GRU rerun over the rollout's T steps.

        A minibatch holds ``max(1, minibatch_size // T)`` of the B * N agent sequences, the GRU rerun from
        :attr:`start_hidden` (truncated back-propagation through time at rollout boundaries).
        """
        s, model, n, t = self.settings, self.model, self.n_agents, self.settings.rollout_steps
        sequences = self.n_envs * n
        obs = self.obs.reshape(t, sequences, self.obs_size)
        actions = self.actions.reshape(t, sequences, self.action_size)
        old_log_probs = self.log_probs.reshape(t, sequences)
        start = self.start_hidden.reshape(sequences, -1)
        if self.central:
            per_agent = advantages[:, :, None].expand(-1, -1, n).reshape(t, sequences)
            states, value_targets = self.states, targets  # [T, B, S], [T, B]
        else:
            per_agent, value_targets = advantages.reshape(t, sequences), targets.reshape(t, sequences)

        def step(index: torch.Tensor) -> torch.Tensor:
            mean, _ = model.actor.sequence(obs[:, index], start[index])
            if self.central:
                episodes = torch.unique(torch.div(index, n, rounding_mode="floor"))
                value = model.critic(states[:, episodes]).squeeze(-1)
                target = value_targets[:, episodes]
            else:
                value = model.critic(obs[:, index]).squeeze(-1)
                target = value_targets[:, index]
            return self._minibatch_step(
                mean, actions[:, index], old_log_probs[:, index], per_agent[:, index], value, target
            )

        return self._passes(sequences, max(1, s.minibatch_size // t), step)

    def _update_graphs(self, advantages: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """``gnn``: minibatches of whole (step, episode) graphs, ``max(1, minibatch_size // N)`` of them."""
        s, model, n, t = self.settings, self.model, self.n_agents, self.settings.rollout_steps
        graphs = t * self.n_envs
        obs = self.obs.reshape(graphs, n, self.obs_size)
        actions = self.actions.reshape(graphs, n, self.action_size)
        old_log_probs = self.log_probs.reshape(graphs, n)
        edge_index = self.edge_index.reshape(graphs, 2, self.edge_width)
        edge_mask = self.edge_mask.reshape(graphs, self.edge_width)
        if self.central:
            per_agent = advantages.reshape(graphs, 1).expand(-1, n)
            states, value_targets = self.states.reshape(graphs, self.state_size), targets.reshape(graphs)
        else:
            per_agent, value_targets = advantages.reshape(graphs, n), targets.reshape(graphs, n)

        def step(index: torch.Tensor) -> torch.Tensor:
            mean = model.actor(obs[index], edge_index[index], edge_mask[index])
            value = model.critic((states if self.central else obs)[index]).squeeze(-1)
            return self._minibatch_step(
                mean, actions[index], old_log_probs[index], per_agent[index], value, value_targets[index]
            )

        return self._passes(graphs, max(1, s.minibatch_size // n), step)


def train_torch(args: TrainArgs) -> Path:
    """Run (or resume) PPO on the batched engine on ``args.device``; returns the run directory."""
    args, params, run, checkpoint, trainer = prepare(args, "torch", PPOSettings, Trainer)
    settings, device = trainer.settings, trainer.device
    per_rollout = settings.rollout_steps * trainer.n_envs * trainer.n_agents
    record = {"torch_ppo": dataclasses.asdict(settings), "timesteps_per_rollout": per_rollout}
    banner = (
        f"fxc train: torch PPO on {env_label(args)} (N = {trainer.n_agents}, one shared policy, {args.critic} critic) "
        f"on {device}: {trainer.n_envs} episodes, {per_rollout} timesteps per rollout"
    )

    def rollout_and_update(start_steps: int, start_time: float) -> tuple[dict[str, Any], str]:
        began = time.perf_counter()
        rollout = trainer.collect()
        collected = time.perf_counter()
        advantages, targets, explained = trainer.advantages(rollout)
        means = trainer.update(advantages, targets)
        trainer.timesteps += per_rollout
        trainer.iterations += 1
        row = progress_row(trainer, rollout, means, explained, start_steps, start_time, began, collected)
        reward, error = row["rollout/ep_rew_mean"], row["rollout/deadline_error"]
        line = (
            f"  rollout {trainer.iterations}: {trainer.timesteps} timesteps, {row['time/fps']:.0f} fps"
            + ("" if reward is None else f", mean episode return {reward:.4g}")
            + ("" if error is None else f", median deadline error {error:.3g}")
        )
        return row, line

    return drive(
        args, run, trainer, checkpoint, params, record, banner, "rollout", rollout_and_update, PROGRESS_COLUMNS
    )


def progress_row(
    trainer: Trainer,
    rollout: dict[str, Any],
    means: torch.Tensor,
    explained: torch.Tensor,
    start_steps: int,
    start_time: float,
    began: float,
    collected: float,
) -> dict[str, Any]:
    """One ``progress.csv`` row (:data:`PROGRESS_COLUMNS`): the one read of the rollout's statistics off the device.

    ``means``: the update's mean policy loss, value loss, entropy loss, approximate KL and
    clip fraction (:meth:`Trainer.update`); ``explained``: the critic's explained variance.
    """
    now = time.perf_counter()
    losses = means.cpu().tolist()
    returns, errors = rollout["returns"], rollout["errors"]
    return {
        "time/iterations": trainer.iterations,
        "time/total_timesteps": trainer.timesteps,
        "time/fps": (trainer.timesteps - start_steps) / max(now - start_time, 1e-9),
        "time/time_elapsed": now - start_time,
        "time/collect_seconds": collected - began,
        "time/update_seconds": now - collected,
        "rollout/ep_rew_mean": None if returns is None else float(returns.mean().item()),
        "rollout/deadline_error": None if errors is None else float(np.median(errors)),
        "rollout/episodes": 0 if returns is None else int(returns.numel()),
        "train/policy_loss": losses[0],
        "train/value_loss": losses[1],
        "train/entropy_loss": losses[2],
        "train/approx_kl": losses[3],
        "train/clip_fraction": losses[4],
        "train/explained_variance": float(explained.item()),
        "train/std": float(torch.exp(trainer.model.log_std.detach()).mean().item()),
        "train/learning_rate": trainer.settings.learning_rate,
        "train/n_updates": trainer.n_updates,
    }
