"""The environment's settings as command-line flags, shared by ``fxc simulate`` and ``fxc evaluate``.

The flags are generated from the arguments' table (:data:`fxc_env.config.arguments.ENV_ARGUMENTS`,
each argument's :class:`~fxc_env.config.arguments.Flag`): ``--n-agents`` is ``n_agents``, with
the table's help, type and choices. Every flag maps to one keyword argument of
:func:`fxc_env.make_config`; a flag left out keeps the scenario's value (or the default).
Numbers that may be ranges or sets are written with commas: ``--u-max 10,100,1000`` (drawn per
episode), ``--position-range 0.5,50`` (a log-uniform range), ``--mean-in-degree 1.5,3`` and
``--topology-period 2,4`` (with ``--family``, which draws a new graph every episode).
"""

from __future__ import annotations

import argparse
from typing import Any

from fxc_env.config.arguments import ENV_ARGUMENTS, Argument, Flag
from fxc_env.config.scenarios import SCENARIOS
from fxc_env.core.graph_kinds import FAMILY_KEYS, FAMILY_KINDS
from fxc_env.core.models import AGENT_MODELS
from fxc_env.core.validation import ArgumentError

#: The arguments that have a flag, in the table's order (``scenario`` first).
FLAG_ARGUMENTS: tuple[Argument, ...] = tuple(argument for argument in ENV_ARGUMENTS if argument.flag is not None)

_ARGPARSE_TYPES = {"int": int, "float": float}
#: ``--order``, ``--damping``, ``--frequency``: the parameter of ``--agent-model``'s spec, read from the model table.
MODEL_FLAGS = {m.parameter: (m.flag_type, m.flag_help) for m in AGENT_MODELS.values() if m.parameter}


def add_env_arguments(parser: argparse.ArgumentParser, *, scenario_default: str | None = "paper_fig1") -> None:
    """Add the environment group of flags (see the module docstring)."""
    group = parser.add_argument_group("environment (a flag left out keeps the scenario's value)")
    for argument in FLAG_ARGUMENTS:
        if argument.name == "scenario":
            group.add_argument(
                argument.flag_name,
                default=scenario_default,
                help=f"named scenario {tuple(SCENARIOS)} or 'none' (the defaults)",
            )
            continue
        group.add_argument(argument.flag_name, **_argparse_options(argument))
        if argument.name == "agent_model":
            for key, (kind, text) in MODEL_FLAGS.items():
                group.add_argument(f"--{key}", type=kind, help=text)
        if argument.name == "topology":
            group.add_argument(
                "--family",
                choices=FAMILY_KINDS,
                help="draw a new graph of this family every episode (random labels; see --mean-in-degree, "
                "--topology-period)",
            )


def _argparse_options(argument: Argument) -> dict[str, Any]:
    """``add_argument``'s keywords for one argument's flag: type, choices and help."""
    flag = argument.flag or Flag()
    options: dict[str, Any] = {"help": flag.help or argument.help}
    if flag.kind in _ARGPARSE_TYPES:
        options["type"] = _ARGPARSE_TYPES[flag.kind]
    choices = flag.choices or (argument.choices if argument.kind == "choice" else None)
    if choices is not None:
        options["choices"] = choices
    return options


def _numbers(flag: str, text: str) -> float | tuple[float, ...]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise ArgumentError(f"{flag}: expected a number or comma-separated numbers, got {text!r}") from None
    return values[0] if len(values) == 1 else values


def env_kwargs_from(args: argparse.Namespace) -> dict[str, Any]:
    """The ``make_config`` keyword arguments (``scenario`` included) that the flags ask for."""
    kwargs: dict[str, Any] = {}
    for argument in FLAG_ARGUMENTS:
        value = getattr(args, argument.name)
        if argument.name == "scenario" or value is None:
            continue
        kwargs[argument.name] = _numbers(argument.flag_name, value) if argument.flag.kind == "numbers" else value
    if kwargs.get("u_max") is not None and isinstance(kwargs["u_max"], tuple):
        kwargs["u_max"] = list(kwargs["u_max"])
    for key in MODEL_FLAGS:
        value = getattr(args, key, None)
        if value is not None:
            if "agent_model" not in kwargs:
                raise ArgumentError(f"--{key}: a parameter of --agent-model; give --agent-model too")
            spec = kwargs["agent_model"] if isinstance(kwargs["agent_model"], dict) else {"name": kwargs["agent_model"]}
            kwargs["agent_model"] = {**spec, key: value}
    if args.family is not None:
        if "topology" in kwargs:
            raise ArgumentError("--family: draws the topology; leave out --topology")
        if "mean_in_degree" not in FAMILY_KEYS[args.family] and "mean_in_degree" in kwargs:
            shaped = " or ".join(kind for kind, keys in FAMILY_KEYS.items() if "mean_in_degree" in keys)
            raise ArgumentError(f"--mean-in-degree: shapes --family {shaped} only, got --family {args.family}")
        family: dict[str, Any] = {"family": args.family}
        for key in ("mean_in_degree", "topology_period"):
            if key in kwargs:
                family["period" if key == "topology_period" else key] = kwargs.pop(key)
        if isinstance(family.get("period"), float):
            family["period"] = _integer_range("--topology-period", family["period"])
        elif isinstance(family.get("period"), tuple):
            family["period"] = tuple(_integer_range("--topology-period", p) for p in family["period"])
        kwargs["topology"] = family
    else:
        for key in ("mean_in_degree", "topology_period"):
            if isinstance(kwargs.get(key), tuple):
                raise ArgumentError(f"--{key.replace('_', '-')}: a LOW,HIGH range needs --family")
        if isinstance(kwargs.get("topology_period"), float):
            kwargs["topology_period"] = _integer_range("--topology-period", kwargs["topology_period"])
    scenario = None if args.scenario in (None, "none") else args.scenario
    return {"scenario": scenario, **kwargs}


def _integer_range(flag: str, value: float) -> int:
    if value != int(value):
        raise ArgumentError(f"{flag}: expected whole numbers, got {value:g}")
    return int(value)
