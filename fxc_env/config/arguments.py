"""The environment's arguments, declared once (docs: environment.md, "The environment").

:func:`fxc_env.make_config` and every front end over it take the same keyword arguments.
:data:`ENV_ARGUMENTS` states each one once (name, type from :class:`EnvKwargs`, default, allowed
values, help, card row); ``make_config``'s fallbacks and checks, the ``fxc`` flags
(:mod:`fxc_env.config.flags`) and every card's Arguments table (:func:`with_arguments_table`) come
from it, and :func:`env_signature` writes the front ends' signatures out for ``help()``.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import Any, TypeVar

from fxc_env.config.argument_types import (
    NO_FALLBACK,
    REQUIRED,
    TABLE_MARKER,
    Argument,
    EnvKwargs,
    Flag,
    arguments_table,
    with_arguments_table,
)
from fxc_env.core import validation
from fxc_env.core.graphs import TOPOLOGY_NAMES
from fxc_env.core.models import FLAT_PARAMETERS, MODEL_NAMES
from fxc_env.core.schedules import SCHEDULE_NAMES

_F = TypeVar("_F", bound=Callable[..., Any])

__all__ = [
    "ARGUMENTS",
    "ENV_ARGUMENTS",
    "ENV_ARGUMENT_NAMES",
    "FRONT_END_ARGUMENTS",
    "GRAPH_TENSORS",
    "MAX_CYCLES",
    "NO_FALLBACK",
    "RENDER_MODE",
    "REQUIRED",
    "TABLE_MARKER",
    "Argument",
    "EnvKwargs",
    "Flag",
    "arguments_table",
    "env_arguments",
    "env_signature",
    "with_arguments_table",
]


#: Each environment argument's annotation, as the signatures write it (EnvKwargs's, and ``scenario``'s).
_ANNOTATIONS = {"scenario": "str | None", **{k: v.__forward_arg__ for k, v in EnvKwargs.__annotations__.items()}}


def _env(name: str, default: Any, **fields: Any) -> Argument:
    """A row of the table, annotated as :class:`EnvKwargs` types it."""
    return Argument(name, _ANNOTATIONS[name], default, **fields)


#: Half-widths of the action Box per (action_mode, obs_mode), the default of ``action_bound``.
#: Normalised bounds hold the reference for every state (its plan is at most 2 and 1, its
#: accel ends at most 10 and 8); a residual's box is the plan's, around the reference's plan. Raw bounds are nominal: no fixed bound holds every graph and
#: scale. They hold the reference from the documented random initial ranges on every built-in
#: topology up to N = 100 (the slowest, a 100-ring, peaks near 4e7 m/s^2 in accel mode); pass
#: ``action_bound`` for larger or slower-mixing cases.
DEFAULT_ACTION_BOUNDS = {
    ("plan", "normalized"): 2.0,
    ("accel", "normalized"): 10.0,
    ("residual", "normalized"): 2.0,
    ("plan_balanced", "normalized"): 1.0,
    ("plan", "raw"): 1.0e3,
    ("residual", "raw"): 1.0e3,
    ("plan_balanced", "raw"): 1.0e3,
    ("accel", "raw"): 1.0e9,
}

RENDER_MODES = ("human", "rgb_array")

#: The arguments of :func:`fxc_env.make_config`, in its signature's order (``scenario`` first,
#: positional; every other one keyword-only).
ENV_ARGUMENTS: tuple[Argument, ...] = (
    _env(
        "scenario",
        None,
        help="named scenario or 'none' (the defaults)",
        card='named preset from ``fxc_env.SCENARIOS`` (e.g. ``"paper_fig1"``, the paper\'s example)',
        flag=Flag(),
    ),
    _env(
        "n_agents",
        None,
        help="number of agents N",
        card="N for a named topology or a family",
        kind="integer",
        minimum=validation.MIN_AGENTS,
        maximum=validation.MAX_AGENTS,
        fallback=6,
        from_scenario=True,
        flag=Flag("int"),
    ),
    _env(
        "topology",
        None,
        help=", ".join(TOPOLOGY_NAMES[1:] + TOPOLOGY_NAMES[:1]),
        card='``"paper_fig1"`` (the **assumed** Fig. 1), ``"ring"``, ``"path"``, ``"star"``, ``"complete"``, '
        '``"random"``; edges ``(j, i)``: i receives from j; a family (``fxc_env.core.families.make_family``) '
        "is drawn anew at every reset",
        fallback="paper_fig1",
        from_scenario=True,
        card_type="name, edge list, list of edge lists, DiGraph(s), family",
        flag=Flag(),
    ),
    _env(
        "settling_time",
        None,
        help="deadline T_s in seconds",
        card="the deadline ``T_s`` (s)",
        fallback=20.0,
        from_scenario=True,
        flag=Flag("float"),
    ),
    _env(
        "n_intervals",
        None,
        help="number of sampling intervals K",
        card="K, the number of sampling intervals (of a named schedule)",
        fallback=200,
        from_scenario=True,
        flag=Flag("int"),
    ),
    _env(
        "schedule",
        None,
        help="sampling schedule",
        card="the sampling instants (``T_k = 6 T_s / (pi k)^2``, last interval ending at ``T_s``)",
        fallback="paper",
        from_scenario=True,
        card_type="``" + " \\| ".join(f'"{name}"' for name in SCHEDULE_NAMES) + "`` or interval lengths",
        flag=Flag(choices=SCHEDULE_NAMES),
    ),
    _env(
        "dim",
        None,
        help="space dimension n",
        card="space dimension of ``x_i, v_i, u_i``",
        kind="integer",
        minimum=1,
        maximum=validation.MAX_DIM,
        fallback=1,
        from_scenario=True,
        flag=Flag("int"),
    ),
    _env(
        "action_mode",
        "plan",
        help="what an action is: a planned terminal change (plan, default; plan_balanced: its velocity in "
        "units of s_i / T_s, both parts weighed as the deadline's D weighs them), the input at both ends (accel) "
        "or a correction added to the paper's plan (residual: the zero action is the reference)",
        card="meaning of an action (Action Space)",
        kind="choice",
        choices=("plan", "plan_balanced", "accel", "residual"),
        flag=Flag(),
    ),
    _env(
        "obs_mode",
        "normalized",
        help="scale-free (normalized, default) or physical (raw) observations and actions",
        card="scale-free or physical observations and actions",
        kind="choice",
        choices=("normalized", "raw"),
        flag=Flag(),
    ),
    _env(
        "obs_format",
        "flat",
        help="one Box per agent (flat, default) or a dict of neighbours, mask and clock",
        card='one Box, or ``{"neighbours", "mask", "clock"}``',
        kind="choice",
        choices=("flat", "dict"),
    ),
    _env(
        "obs_dtype",
        "float64",
        help="dtype of observations, their spaces and the normalized global state",
        card="dtype of observations, their spaces and the normalized global state",
        kind="choice",
        choices=("float64", "float32"),
    ),
    _env(
        "global_state",
        "raw",
        help="what state() returns: absolute rows (raw, default) or the scale-free vector (normalized)",
        card="what ``state()`` returns (State)",
        kind="choice",
        choices=("raw", "normalized"),
    ),
    _env(
        "action_bound",
        None,
        help="half-width b of the action Box (default: by action_mode and obs_mode)",
        card="half-width ``b`` of the action Box (default: the Action Space table's, by ``action_mode`` and "
        "``obs_mode``)",
        kind="real",
        positive=True,
        card_default="by mode",
    ),
    _env(
        "reward_floor",
        1e-12,
        help="f / D(0), the floor in the log reward (at most 1: a floor above D(0) leaves every reward 0)",
        card="``f / D(0)`` in the reward, in (0, 1]",
        kind="real",
        maximum=1.0,
        positive=True,
    ),
    _env(
        "initial_state",
        None,
        help="a fixed initial state (x0, v0), or 'random' to drop the scenario's",
        card='fixed initial state ``(N, dim)`` arrays; ``"random"`` drops the scenario\'s',
        from_scenario=True,
        card_type='``None \\| "random" \\| (x0, v0)``',
        card_default="[random]",
    ),
    _env(
        "position_range",
        None,
        help="initial positions U(-r, r) m; LOW,HIGH draws r log-uniformly",
        card="initial positions ``U(-r, r)`` (m); a pair draws ``r`` log-uniformly per episode",
        fallback=5.0,
        from_scenario=True,
        card_type="``float \\| (low, high) \\| None``",
        flag=Flag("numbers"),
    ),
    _env(
        "velocity_range",
        None,
        help="initial velocities U(-r, r) m/s; LOW,HIGH as above",
        card="initial velocities ``U(-r, r)`` (m/s); a pair as above",
        fallback=2.0,
        from_scenario=True,
        card_type="``float \\| (low, high) \\| None``",
        flag=Flag("numbers"),
    ),
    _env(
        "topology_seed",
        0,
        help="seed of the random topology (default 0)",
        card='seed of ``topology="random"`` (of a family: the draw ``config.topology`` shows)',
        kind="seed",
        flag=Flag("int"),
    ),
    _env(
        "mean_in_degree",
        None,
        help="mean in-degree of random digraphs; LOW,HIGH draws it with --family",
        card='mean in-degree of ``"random"``',
        fallback=2.0,
        from_scenario=True,
        flag=Flag("numbers"),
    ),
    _env(
        "topology_period",
        None,
        help="graphs per switching period (random, or LOW,HIGH with --family)",
        card='number of switching graphs of ``"random"``',
        fallback=1,
        from_scenario=True,
        flag=Flag("numbers"),
    ),
    _env(
        "obs_slots",
        None,
        help="neighbour rows of the observation (a learned policy's width)",
        card="neighbour rows in an observation (at least ``d_max``, at most N)",
        from_scenario=True,
        card_default="``d_max``",
        flag=Flag("int"),
    ),
    _env(
        "u_max",
        None,
        help="input limit (m/s^2); A,B,C draws one per episode",
        card="clips each input component to ``±u_max`` m/s^2, integrated exactly (infos report the saturated "
        "share); a set draws one limit per episode",
        from_scenario=True,
        card_type="``float \\| set of floats \\| None``",
        flag=Flag("numbers"),
    ),
    _env(
        "obs_noise",
        0.0,
        help="standard deviation of measurement noise (m, m/s)",
        card="standard deviation of Gaussian noise (m, m/s) on each relative measurement",
        kind="real",
        minimum=0.0,
        maximum=validation.STATE_LIMIT,
        flag=Flag("float"),
    ),
    _env(
        "obs_resolution",
        None,
        help="measurement quantum (m, m/s): each row is rounded to a multiple of it (default: exact)",
        card="quantum (m, m/s) each relative measurement is rounded to (after noise); ``None`` or 0: exact rows. "
        "Infos report the resolution floor (docs: optimality.md)",
        kind="real",
        minimum=0.0,
        maximum=validation.STATE_LIMIT,
        card_type="``float \\| None``",
        flag=Flag("float"),
    ),
    _env(
        "link_dropout",
        0.0,
        help="probability that an edge is lost at a sampling instant",
        card="probability in [0, 1) that an edge is lost at a sampling instant (the mask shows it)",
        kind="probability",
        flag=Flag("float"),
    ),
    _env(
        "switching",
        "periodic",
        help="cycle through the graphs (periodic, default) or draw each interval's graph (random)",
        card="cycle through the graphs, or draw each interval's graph",
        kind="choice",
        choices=("periodic", "random"),
        flag=Flag(),
    ),
    _env(
        "agent_model",
        None,
        help="the agents' dynamics per axis (default double_integrator; docs: agent-models.md)",
        card='the agents\' model per axis: a name, ``"single_integrator"``, ``"integrator_chain"``, ``"damped"``, '
        '``"oscillator"``, a dict with its parameter (``{"name": "damped", "damping": 0.5}``: ``order`` 1-4, '
        '``damping`` c in 1/s, ``frequency`` ω in rad/s), or a controllable pair ``(A, B)`` (docs: agent-models.md, "Agent models and formations")',
        fallback="double_integrator",
        from_scenario=True,
        card_type="name, dict or ``(A, B)``",
        flag=Flag(choices=MODEL_NAMES),
    ),
    _env(
        "formation_offsets",
        None,
        help="formation offsets h_i: positions (N, dim) or full states (N, dim, n)",
        card='agents agree on ``z_i - e^{A t} h_i``: position offsets hold a formation (docs: agent-models.md, "Formations")',
        from_scenario=True,
        card_type="``(N, dim)`` or ``(N, dim, n)`` array",
    ),
)

#: Front-end arguments beside the environment's: frames and truncation.
RENDER_MODE = Argument(
    "render_mode",
    "str | None",
    None,
    help="frames of episode 0: None, 'human' or 'rgb_array'",
    card="frames of episode 0 so far",
    kind="choice",
    choices=RENDER_MODES,
)
MAX_CYCLES = Argument(
    "max_cycles",
    "int | None",
    None,
    help="truncate after this many steps (None: run to T_s)",
    card="truncate after this many steps",
    kind="integer",
    minimum=1,
)
FRONT_END_ARGUMENTS: tuple[Argument, ...] = (RENDER_MODE, MAX_CYCLES)
#: The graph as edge tensors for graph neural networks (docs: graph-tensors.md, "Graph tensors"): taken by the
#: TorchRL environment (root keys) and the PettingZoo parallel env (per-step infos) only.
GRAPH_TENSORS = Argument(
    "graph_tensors",
    "bool",
    False,
    help="add the current graph as edge_index / edge_mask / n_edges / edge_attr",
    card="the current interval's graph as PyG-style edge tensors, ``edge_index`` (source j, target i) and "
    '``edge_attr`` (the observation\'s rows ``z_j - z_i``) (docs: graph-tensors.md, "Graph tensors")',
    kind="boolean",
)

#: The keywords of :func:`fxc_env.make_config`, in order.
ENV_ARGUMENT_NAMES: tuple[str, ...] = tuple(argument.name for argument in ENV_ARGUMENTS)
#: Every argument above by name.
ARGUMENTS: Mapping[str, Argument] = MappingProxyType(
    {argument.name: argument for argument in (*ENV_ARGUMENTS, *FRONT_END_ARGUMENTS)}
)


def env_arguments(namespace: Mapping[str, Any], kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The :func:`fxc_env.make_config` keywords (every one, in order) out of a front end's ``locals()`` and ``**kwargs``.

    An argument in neither takes the table's default; the deprecated ``order``, ``damping`` and
    ``frequency`` (:mod:`fxc_env.core.models`) pass through when given.

    Raises:
        ArgumentTypeError naming a keyword of ``kwargs`` that is no argument of the environment.
    """
    extra = kwargs or {}
    for name in extra:
        if name not in ENV_ARGUMENT_NAMES and name not in FLAT_PARAMETERS:
            raise validation.ArgumentTypeError(
                f"{name}: not an argument of the environment; expected one of {', '.join(ENV_ARGUMENT_NAMES)}"
            )
    given = {**namespace, **extra}
    arguments = {name: given.get(name, ARGUMENTS[name].default) for name in ENV_ARGUMENT_NAMES}
    return {**arguments, **{name: extra[name] for name in FLAT_PARAMETERS if name in extra}}  # deprecated aliases


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
