"""Versioned entry point, PettingZoo style: ``env``, ``parallel_env`` and ``raw_env``.

* ``raw_env``: the unwrapped AEC environment, :class:`~fxc_env.envs.aec.ConsensusAECEnv`.
* ``env(...)``: ``raw_env(...)`` in PettingZoo's ``OrderEnforcingWrapper``. Out-of-Box
  actions are applied by design, so no clipping or bounds-asserting wrapper is added.
* ``parallel_env(...)``: :class:`~fxc_env.envs.parallel.ConsensusParallelEnv`.

All three take the same arguments (the table in the environment's card, ``help(raw_env)``).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

from pettingzoo.utils import wrappers

from fxc_env.envs.aec import ConsensusAECEnv
from fxc_env.envs.parallel import ConsensusParallelEnv

__all__ = ["env", "parallel_env", "raw_env"]

_P = ParamSpec("_P")
_R = TypeVar("_R")

#: The unwrapped AEC environment class (PettingZoo's convention for ``raw_env``).
raw_env = ConsensusAECEnv


def _takes_arguments_of(cls: Callable[_P, Any]) -> Callable[[Callable[..., _R]], Callable[_P, _R]]:
    """Give the decorated factory the signature of ``cls`` (for ``help``, ``inspect`` and type checkers)."""

    def decorate(function: Callable[..., _R]) -> Callable[_P, _R]:
        return_annotation = inspect.signature(function).return_annotation
        function.__signature__ = inspect.signature(cls).replace(return_annotation=return_annotation)  # type: ignore[attr-defined]
        return function

    return decorate


@_takes_arguments_of(ConsensusParallelEnv)
def parallel_env(*args: Any, **kwargs: Any) -> ConsensusParallelEnv:
    """The parallel environment; arguments as in :class:`ConsensusParallelEnv` (its card has the table)."""
    return ConsensusParallelEnv(*args, **kwargs)


@_takes_arguments_of(ConsensusAECEnv)
def env(*args: Any, **kwargs: Any) -> wrappers.OrderEnforcingWrapper:
    """The AEC environment in PettingZoo's order-enforcing wrapper; arguments as in :func:`parallel_env`."""
    return wrappers.OrderEnforcingWrapper(ConsensusAECEnv(*args, **kwargs))
