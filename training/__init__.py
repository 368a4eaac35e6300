"""Training of learned policies: stable-baselines3 (:mod:`.sb3_train`), Ray RLlib (:mod:`.rllib_train`)
or a lean torch PPO loop (:mod:`.torch_ppo`), in one run-directory layout (:mod:`.run_dir`).

>>> from fxc_env.training import TrainArgs, train
>>> train(TrainArgs(scenario="paper_fig1", timesteps=100_000))  # doctest: +SKIP
"""

from __future__ import annotations

from fxc_env.training.args import TrainArgs
from fxc_env.training.backends import train

__all__ = ["TrainArgs", "train"]
