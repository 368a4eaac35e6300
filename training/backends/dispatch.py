"""Which back end trains: ``fxc train --backend sb3|rllib|torch|diff`` lands in :func:`train`.

Each back end is imported only when chosen (:mod:`fxc_env.training.registry`); they share
:class:`fxc_env.training.args.TrainArgs` and the run directory (:mod:`fxc_env.training.run_dir`).
"""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

from fxc_env.core import validation
from fxc_env.training import registry
from fxc_env.training.args import BACKENDS, TrainArgs, canonical_backend
from fxc_env.training.run_dir import RunDir
from fxc_env.utils.cluster import import_ray


def train(args: TrainArgs) -> Path:
    """Run (or resume) training on ``args.backend``; returns the run directory."""
    backend = validation.choice("backend", canonical_backend(args.backend), BACKENDS)  # the back end checks the rest
    args = dataclasses.replace(args, backend=backend)
    if backend == "rllib":
        RunDir.of(args).resume_checkpoint(args.resume, args)  # an RLlib checkpoint needs the trust flag, Ray or not
        import_ray("--backend rllib")
    module, function = registry.BACKENDS[backend].trainer.split(":")
    return getattr(importlib.import_module(f"fxc_env.training.backends.{module}"), function)(args)
