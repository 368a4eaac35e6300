"""``fxc train --backend diff``: analytic policy gradients through the engine's closed-form intervals.

The loop plays B episodes (:class:`fxc_env.engine.ConsensusEngine`, float64 on ``--device``) with the
deterministic policy (the actor's mean clipped to ``±action_bound``) and descends, with Adam after clipping
the gradient's norm to ``max_grad_norm``, the gradient of

    loss = log_error:  mean over episodes of ln D(T_s) / D(0)  (the default; the paper's measure)
           return:     minus the mean episode return

``window`` (K, or a divisor of K) truncates the back-propagation; settings are the ``diff_apg`` entry
(:class:`DiffSettings`) (docs: differentiable.md, "Differentiable simulation").
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from fxc_env.config import make_config
from fxc_env.policies.torch_memory import interval_graph
from fxc_env.training.args import TrainArgs, env_label
from fxc_env.training.backends.torch_common import drive, prepare, run_config
from fxc_env.training.backends.torch_ppo import Trainer
from fxc_env.training.settings import DiffSettings

#: Columns of ``progress.csv``, SB3's names where they mean the same.
PROGRESS_COLUMNS = (
    "time/iterations",
    "time/total_timesteps",
    "time/fps",
    "time/time_elapsed",
    "rollout/ep_rew_mean",
    "rollout/deadline_error",
    "rollout/log_deadline_error",
    "rollout/episodes",
    "train/loss",
    "train/grad_norm",
    "train/learning_rate",
    "train/n_updates",
)
#: Below this D(t) the log is taken of the floor instead (an exact 0 would give -inf and a NaN gradient).
TINY = 1e-300


def cut_graph(engine: Any) -> None:
    """Detach every tensor the engine and its parts hold, so the next loss's graph starts here.

    Needed between truncated windows, and before each reset (a reset writes in place into the previous
    episode's tensor, keeping its graph: issue 26, item 1).
    """
    seen: set[int] = set()

    def walk(part: Any) -> None:
        for key, value in list(vars(part).items()):
            if isinstance(value, torch.Tensor):
                if value.requires_grad:
                    setattr(part, key, value.detach())
            elif type(value).__module__.startswith("fxc_env.") and hasattr(value, "__dict__") and id(value) not in seen:
                seen.add(id(value))
                walk(value)

    walk(engine)
    engine.observer.invalidate()  # cached measurements of the state before the cut


class DiffTrainer(Trainer):
    """The torch back end's trainer (engine, networks, Adam, generators, files), stepped by analytic gradients."""

    def __init__(self, args: TrainArgs, params: dict[str, Any], settings: DiffSettings, device: torch.device) -> None:
        self.diff = settings
        k_intervals = make_config(**run_config(args, params)).n_intervals
        super().__init__(args, params, settings.ppo(k_intervals), device)
        self.k_intervals = k_intervals
        self.window = settings.window or k_intervals
        self.model.critic.requires_grad_(False)  # the shared trainer's critic: no part of the gradient here
        self.model.log_std.requires_grad_(False)  # the policy is deterministic; kept for the policy file

    def _reset(self) -> None:
        cut_graph(self.engine)  # workaround, see cut_graph; drop with the engine's fix
        super()._reset()

    def _act(self, obs: torch.Tensor, hidden: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        actor = self.model.actor
        if self.arch == "gru":
            return actor.step(obs, hidden)
        if self.arch == "gnn":
            return actor(obs, *interval_graph(self.engine, obs, self.edge_width)), None
        return actor(obs), None

    def episode(self) -> dict[str, Any]:
        """Play one batch of B episodes with K / window gradient steps; returns its statistics."""
        engine, s = self.engine, self.diff
        if not self.fresh:  # fresh: just built, or resumed (whose episodes are drawn as the run's would have been)
            self._reset()
        self.fresh = False
        dtype = engine.dtype
        hidden = (
            self.model.actor.initial_state((self.n_envs, self.n_agents), self.device) if self.arch == "gru" else None
        )
        log_d0 = torch.log(engine.initial_disagreement.clamp_min(TINY))
        returns = torch.zeros(self.n_envs, dtype=dtype, device=self.device)
        losses, norms = [], []
        for _ in range(self.k_intervals // self.window):
            log_start = torch.log(engine.current_disagreement.clamp_min(TINY))
            window_return = torch.zeros_like(returns)
            for _ in range(self.window):
                mean, hidden = self._act(engine.observations().to(torch.float32), hidden)
                actions = mean.clamp(-self.bound, self.bound).to(dtype)
                window_return = window_return + engine.step(engine.validate_actions(actions)).reward
            if s.loss == "return":
                loss = -window_return.mean()
            else:
                loss = (torch.log(engine.current_disagreement.clamp_min(TINY)) - log_start).mean()
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            norms.append(nn.utils.clip_grad_norm_(self.model.actor.parameters(), s.max_grad_norm).detach())
            self.optimizer.step()
            self.n_updates += 1
            losses.append(loss.detach())
            returns += window_return.detach()
            cut_graph(engine)
            hidden = None if hidden is None else hidden.detach()
        engine.raise_if_invalid()
        log_error = torch.log(engine.current_disagreement.clamp_min(TINY)) - log_d0
        return {
            "returns": returns,
            "errors": engine.batch_metrics()["relative_deadline_error"],
            "log_error": float(log_error.mean().item()),
            "loss": float(torch.stack(losses).sum().item()),
            "grad_norm": float(torch.stack(norms).mean().item()),
        }


def train_diff(args: TrainArgs) -> Path:
    """Run (or resume) analytic policy gradients on the engine on ``args.device``; returns the run directory."""
    args, params, run, checkpoint, trainer = prepare(args, "diff", DiffSettings, DiffTrainer)
    settings, device = trainer.diff, trainer.device
    per_batch = trainer.k_intervals * trainer.n_envs * trainer.n_agents
    record = {"diff_apg": dataclasses.asdict(settings), "timesteps_per_batch": per_batch}
    banner = (
        f"fxc train: analytic policy gradients on {env_label(args)} (N = {trainer.n_agents}, one shared policy) on "
        f"{device}: {trainer.n_envs} episodes, {trainer.k_intervals // trainer.window} gradient steps, "
        f"{per_batch} timesteps per batch"
    )

    def episodes_and_steps(start_steps: int, start_time: float) -> tuple[dict[str, Any], str]:
        stats = trainer.episode()
        trainer.timesteps += per_batch
        trainer.iterations += 1
        now = time.perf_counter()
        row = {
            "time/iterations": trainer.iterations,
            "time/total_timesteps": trainer.timesteps,
            "time/fps": (trainer.timesteps - start_steps) / max(now - start_time, 1e-9),
            "time/time_elapsed": now - start_time,
            "rollout/ep_rew_mean": float(stats["returns"].mean().item()),
            "rollout/deadline_error": float(np.median(stats["errors"])),
            "rollout/log_deadline_error": stats["log_error"],
            "rollout/episodes": trainer.n_envs,
            "train/loss": stats["loss"],
            "train/grad_norm": stats["grad_norm"],
            "train/learning_rate": settings.learning_rate,
            "train/n_updates": trainer.n_updates,
        }
        line = (
            f"  batch {trainer.iterations}: {trainer.timesteps} timesteps, loss {stats['loss']:.4g}, "
            f"median deadline error {row['rollout/deadline_error']:.3g}"
        )
        return row, line

    return drive(
        args,
        run,
        trainer,
        checkpoint,
        params,
        record,
        banner,
        "batch of episodes",
        episodes_and_steps,
        PROGRESS_COLUMNS,
    )
