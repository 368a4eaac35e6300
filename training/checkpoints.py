"""Checkpoints of a training run: ``checkpoints/model_<timesteps>_steps.zip`` (+ VecNormalize statistics).

A checkpoint holds the policy, the optimiser state and the step count (SB3's ``save``);
VecNormalize statistics, when used, sit beside it under SB3's naming.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from fxc_env.training.run_files import newest_by_steps

CHECKPOINT_PATTERN = re.compile(r"model_(\d+)_steps\.zip$")


def vecnormalize_path(checkpoint: Path) -> Path:
    """Where the VecNormalize statistics of ``checkpoint`` are kept (SB3's naming)."""
    steps = CHECKPOINT_PATTERN.search(checkpoint.name).group(1)  # type: ignore[union-attr]
    return checkpoint.with_name(f"model_vecnormalize_{steps}_steps.pkl")


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint with the most steps in ``run_dir/checkpoints`` (None if there is none)."""
    return newest_by_steps(run_dir / "checkpoints", "model_*_steps.zip", CHECKPOINT_PATTERN)


def save_checkpoint(model: Any, directory: Path) -> Path:
    """Save ``model`` (optimiser included) and any VecNormalize statistics as ``model_<steps>_steps``."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"model_{model.num_timesteps}_steps.zip"
    model.save(path)
    env = model.get_env()
    if isinstance(env, VecNormalize):
        env.save(str(vecnormalize_path(path)))
    return path


class RolloutCheckpoint(BaseCallback):
    """Save a checkpoint every ``every`` timesteps, at the start of a rollout.

    That is just after the previous rollout's update. SB3's CheckpointCallback saves inside
    a rollout, before its update, so resuming from it would replay the rollout's steps
    without their gradient update.
    """

    def __init__(self, directory: Path, every: int) -> None:
        super().__init__()
        self.directory = directory
        self.every = every
        self.last = 0

    def _on_training_start(self) -> None:
        self.last = self.model.num_timesteps

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps - self.last >= self.every:
            save_checkpoint(self.model, self.directory)
            self.last = self.model.num_timesteps

    def _on_step(self) -> bool:
        return True
