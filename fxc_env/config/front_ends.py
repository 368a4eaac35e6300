"""How the front ends take the environment's arguments: typed ``**kwargs`` and a written-out signature.

Every front end (the PettingZoo parallel and AEC environments, the SB3 ``ConsensusVecEnv``,
the TorchRL ``ConsensusTorchEnv``) takes its own arguments by name and the environment's as
``**kwargs: Unpack[EnvKwargs]``, so type checkers and IDEs see each one; :func:`env_signature`
gives ``help()``, ``inspect`` and the docs the whole signature with the table's defaults
(:data:`fxc_env.config.arguments.ENV_ARGUMENTS`), and :func:`fxc_env.config.arguments.env_arguments`
collects the :func:`fxc_env.make_config` keywords, refusing an unknown one by name.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from typing import Any, TypedDict, TypeVar

from fxc_env.config.argument_types import Argument
from fxc_env.config.arguments import ENV_ARGUMENTS

_F = TypeVar("_F", bound=Callable[..., Any])


class EnvKwargs(TypedDict, total=False):
    """The environment's keyword arguments after ``scenario`` (:data:`ENV_ARGUMENTS`), as front ends take them.

    ``**kwargs: Unpack[EnvKwargs]`` lets type checkers and IDEs see each one; :func:`env_signature`
    writes them out with their defaults for ``help()`` and ``inspect``.
    """

    n_agents: int | None
    topology: Any
    settling_time: float | None
    n_intervals: int | None
    schedule: Any
    dim: int | None
    action_mode: str
    obs_mode: str
    obs_format: str
    obs_dtype: str
    global_state: str
    action_bound: float | None
    reward_floor: float
    initial_state: Any
    position_range: float | tuple[float, float] | None
    velocity_range: float | tuple[float, float] | None
    topology_seed: int | None
    mean_in_degree: float | None
    topology_period: int | None
    obs_slots: int | None
    u_max: float | Sequence[float] | None
    obs_noise: float
    link_dropout: float
    switching: str
    agent_model: Any
    order: int | None
    damping: float | None
    frequency: float | None
    formation_offsets: Any


def env_signature(before: Sequence[Argument] = (), after: Sequence[Argument] = ()) -> Callable[[_F], _F]:
    """Give a front end's ``__init__`` the signature ``(self, *before, *ENV_ARGUMENTS, *after)`` from the table.

    The first argument is positional when it is ``scenario`` or ``n_envs``; every other one is
    keyword-only, with the table's default and annotation.
    """
    P = inspect.Parameter
    parameters = [P("self", P.POSITIONAL_OR_KEYWORD)]
    for position, argument in enumerate((*before, *ENV_ARGUMENTS, *after)):
        kind = P.POSITIONAL_OR_KEYWORD if position == 0 and argument.name in ("scenario", "n_envs") else P.KEYWORD_ONLY
        parameters.append(P(argument.name, kind, default=argument.default, annotation=argument.annotation))
    signature = inspect.Signature(parameters, return_annotation="None")

    def decorate(init: _F) -> _F:
        init.__signature__ = signature  # type: ignore[attr-defined]
        return init

    return decorate
