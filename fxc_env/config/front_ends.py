"""The front ends' signature: the environment's arguments as ``**kwargs: Unpack[EnvKwargs]`` (for type
checkers and IDEs), written out from the table by :func:`env_signature` (for ``help()`` and ``inspect``)."""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from fxc_env.config.argument_types import Argument
from fxc_env.config.arguments import ENV_ARGUMENTS

_F = TypeVar("_F", bound=Callable[..., Any])


def env_signature(
    before: Sequence[Argument] = (), after: Sequence[Argument] = (), *, returns: str | None = None
) -> Callable[[_F], _F]:
    """Give a front end's ``__init__`` the signature ``(self, *before, *ENV_ARGUMENTS, *after)`` from the table.

    The first argument is positional when it is ``scenario`` or ``n_envs``; every other one is
    keyword-only, with the table's default and annotation. With ``returns`` (a function such as
    :func:`fxc_env.make_config`): no ``self``, and that return annotation.
    """
    P = inspect.Parameter
    parameters = [] if returns else [P("self", P.POSITIONAL_OR_KEYWORD)]
    for position, argument in enumerate((*before, *ENV_ARGUMENTS, *after)):
        kind = P.POSITIONAL_OR_KEYWORD if position == 0 and argument.name in ("scenario", "n_envs") else P.KEYWORD_ONLY
        parameters.append(P(argument.name, kind, default=argument.default, annotation=argument.annotation))
    signature = inspect.Signature(parameters, return_annotation=returns or "None")

    def decorate(init: _F) -> _F:
        init.__signature__ = signature  # type: ignore[attr-defined]
        return init

    return decorate
