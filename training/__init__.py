"""Training of learned policies: stable-baselines3 (:mod:`.train`) or Ray RLlib (:mod:`.rllib_train`).

>>> from fxc_env.training import TrainArgs, train
>>> train(TrainArgs(scenario="paper_fig1", timesteps=100_000))  # doctest: +SKIP
"""

from __future__ import annotations

from fxc_env.training.args import TrainArgs
from fxc_env.training.backends import train

__all__ = ["TrainArgs", "train"]
