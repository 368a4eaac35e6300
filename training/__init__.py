"""Training of learned policies: stable-baselines3, Ray RLlib, a lean torch PPO loop or analytic policy
gradients (:mod:`.backends`), in one run-directory layout (:mod:`.run_dir`); their scores over seeds and the
leaderboard (:mod:`.evaluation`); the recipes that rebuild the shipped policies (:mod:`.recipes`).

>>> from fxc_env.training import TrainArgs, train
>>> train(TrainArgs(scenario="paper_fig1", timesteps=100_000))  # doctest: +SKIP
"""

from __future__ import annotations

from fxc_env.training.args import TrainArgs
from fxc_env.training.backends import train

__all__ = ["TrainArgs", "train"]
