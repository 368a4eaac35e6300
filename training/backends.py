"""Which back end trains: ``fxc train --backend sb3|rllib|torchrl`` lands in :func:`train`.

The back ends share :class:`fxc_env.training.args.TrainArgs` and the run-directory layout;
each is imported only when chosen (Ray is an optional extra; ``torchrl`` is the lean torch PPO
loop of :mod:`fxc_env.training.torch_ppo`, on the engine's torch tensors).
"""

from __future__ import annotations

from pathlib import Path

from fxc_env.core import validation
from fxc_env.training.args import BACKENDS, TrainArgs


def train(args: TrainArgs) -> Path:
    """Run (or resume) training on ``args.backend``; returns the run directory."""
    validation.choice("backend", args.backend, BACKENDS)  # the back end checks everything else
    if args.backend == "rllib":
        from fxc_env.utils.cluster import import_ray

        import_ray("--backend rllib")
        from fxc_env.training.rllib_train import train_rllib

        return train_rllib(args)
    if args.backend == "torchrl":
        from fxc_env.training.torch_ppo import train_torch

        return train_torch(args)
    from fxc_env.training.sb3_train import train_sb3

    return train_sb3(args)
