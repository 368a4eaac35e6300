"""The environment's settings as command-line flags, shared by ``fxc simulate`` and ``fxc evaluate``.

Every flag maps to one keyword argument of :func:`fxc_env.make_config`; a flag left out keeps
the scenario's value (or the default). Numbers that may be ranges or sets are written with
commas: ``--u-max 10,100,1000`` (drawn per episode), ``--position-range 0.5,50`` (a
log-uniform range), ``--mean-in-degree 1.5,3`` and ``--topology-period 2,4`` (with
``--family``, which draws a new graph every episode).
"""

from __future__ import annotations

import argparse
from typing import Any

from fxc_env.core.families import FAMILY_KINDS
from fxc_env.core.linear import MODEL_NAMES
from fxc_env.core.validation import ArgumentError

#: Flags whose value is passed through as given (already typed by argparse).
PLAIN_FLAGS = (
    "topology",
    "n_agents",
    "n_intervals",
    "settling_time",
    "schedule",
    "dim",
    "action_mode",
    "obs_mode",
    "topology_seed",
    "obs_slots",
    "obs_noise",
    "link_dropout",
    "switching",
    "agent_model",
    "order",
    "damping",
    "frequency",
)
#: Flags that take a number or comma-separated numbers.
LIST_FLAGS = ("mean_in_degree", "topology_period", "position_range", "velocity_range", "u_max")


def add_env_arguments(parser: argparse.ArgumentParser, *, scenario_default: str | None = "paper_fig1") -> None:
    """Add the environment group of flags (see the module docstring)."""
    from fxc_env.config.scenarios import SCENARIOS

    group = parser.add_argument_group("environment (a flag left out keeps the scenario's value)")
    group.add_argument(
        "--scenario", default=scenario_default, help=f"named scenario {tuple(SCENARIOS)} or 'none' (the defaults)"
    )
    group.add_argument("--topology", help="ring, path, star, complete, random, paper_fig1")
    group.add_argument(
        "--family",
        choices=FAMILY_KINDS,
        help="draw a new graph of this family every episode (random labels; see --mean-in-degree, --topology-period)",
    )
    group.add_argument("--n-agents", type=int, help="number of agents N")
    group.add_argument("--n-intervals", type=int, help="number of sampling intervals K")
    group.add_argument("--settling-time", type=float, help="deadline T_s in seconds")
    group.add_argument("--schedule", choices=("paper", "uniform"), help="sampling schedule")
    group.add_argument("--dim", type=int, help="space dimension n")
    group.add_argument("--action-mode", choices=("plan", "accel"), help="default plan")
    group.add_argument("--obs-mode", choices=("normalized", "raw"), help="default normalized")
    group.add_argument("--topology-seed", type=int, help="seed of the random topology (default 0)")
    group.add_argument("--mean-in-degree", help="mean in-degree of random digraphs; LOW,HIGH draws it with --family")
    group.add_argument("--topology-period", help="graphs per switching period (random, or LOW,HIGH with --family)")
    group.add_argument("--obs-slots", type=int, help="neighbour rows of the observation (a learned policy's width)")
    group.add_argument("--position-range", help="initial positions U(-r, r) m; LOW,HIGH draws r log-uniformly")
    group.add_argument("--velocity-range", help="initial velocities U(-r, r) m/s; LOW,HIGH as above")
    group.add_argument("--u-max", help="input limit (m/s^2); A,B,C draws one per episode")
    group.add_argument("--obs-noise", type=float, help="standard deviation of measurement noise (m, m/s)")
    group.add_argument("--link-dropout", type=float, help="probability that an edge is lost at a sampling instant")
    group.add_argument("--switching", choices=("periodic", "random"), help="default periodic")
    group.add_argument(
        "--agent-model",
        choices=MODEL_NAMES,
        help="the agents' dynamics per axis (default double_integrator; README, 'Agent models')",
    )
    group.add_argument("--order", type=int, help="order of --agent-model integrator_chain (1-4, default 2)")
    group.add_argument("--damping", type=float, help="drag c of --agent-model damped (1/s, default 0.5)")
    group.add_argument("--frequency", type=float, help="frequency of --agent-model oscillator (rad/s, default 1)")


def _numbers(flag: str, text: str) -> float | tuple[float, ...]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise ArgumentError(f"{flag}: expected a number or comma-separated numbers, got {text!r}") from None
    return values[0] if len(values) == 1 else values


def env_kwargs_from(args: argparse.Namespace) -> dict[str, Any]:
    """The ``make_config`` keyword arguments (``scenario`` included) that the flags ask for."""
    kwargs: dict[str, Any] = {name: getattr(args, name) for name in PLAIN_FLAGS if getattr(args, name) is not None}
    for name in LIST_FLAGS:
        text = getattr(args, name)
        if text is not None:
            kwargs[name] = _numbers("--" + name.replace("_", "-"), text)
    if kwargs.get("u_max") is not None and isinstance(kwargs["u_max"], tuple):
        kwargs["u_max"] = list(kwargs["u_max"])
    if args.family is not None:
        if "topology" in kwargs:
            raise ArgumentError("--family: draws the topology; leave out --topology")
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
