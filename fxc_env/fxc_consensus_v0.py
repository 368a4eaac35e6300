"""Versioned entry point, PettingZoo style: ``env``, ``parallel_env`` and ``raw_env``."""

from __future__ import annotations

from typing import Any

from pettingzoo import AECEnv
from pettingzoo.utils.conversions import parallel_to_aec

from fxc_env.consensus_env import ConsensusParallelEnv

#: The unwrapped environment class (parallel-native).
raw_env = ConsensusParallelEnv


def parallel_env(**kwargs: Any) -> ConsensusParallelEnv:
    """The parallel environment; keyword arguments as in :class:`ConsensusParallelEnv`."""
    return ConsensusParallelEnv(**kwargs)


def env(**kwargs: Any) -> AECEnv:
    """The AEC form (PettingZoo's ``parallel_to_aec`` with its order-enforcing wrapper)."""
    return parallel_to_aec(ConsensusParallelEnv(**kwargs))
