"""The environment's arguments, declared once (README, "Using the environment").

:func:`fxc_env.make_config` and every front end over it (the PettingZoo parallel and AEC
environments, the SB3 ``ConsensusVecEnv``, the TorchRL ``ConsensusTorchEnv``) take the same
keyword arguments. :data:`ENV_ARGUMENTS` states each one once: its name, its type as the
signatures write it, its default, the values it allows, a one-line help and its row of the
environment card. From this table come

* ``make_config``'s fallbacks (the ``[value]`` defaults a scenario may override) and its
  checks of single values, through the helpers of :mod:`fxc_env.core.validation`
  (:meth:`Argument.check`), so every message stays the helper's;
* the ``fxc simulate`` / ``fxc evaluate`` environment flags (:mod:`fxc_env.config.flags`);
* the Arguments table of every card (:func:`with_arguments_table`).

The signatures themselves stay written out in each front end, so IDEs, type checkers and
``help()`` see every argument; ``tests/test_arguments.py`` checks that each one agrees with
this table (names, order, defaults, annotations).
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from fxc_env.core import validation
from fxc_env.core.graphs import TOPOLOGY_NAMES
from fxc_env.core.models import DEFAULT_DAMPING, DEFAULT_FREQUENCY, MODEL_NAMES
from fxc_env.core.schedules import SCHEDULE_NAMES

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
    "Argument",
    "Flag",
    "arguments_table",
    "env_arguments",
    "with_arguments_table",
]


class _Marker:
    """A named sentinel (readable in reprs and in the card)."""

    def __init__(self, name: str) -> None:
        self._name = name

    def __repr__(self) -> str:
        return self._name


#: :attr:`Argument.fallback` of an argument that has none.
NO_FALLBACK: Any = _Marker("NO_FALLBACK")
#: :attr:`Argument.default` of an argument the caller must give (``n_envs``).
REQUIRED: Any = inspect.Parameter.empty

#: The checks :meth:`Argument.check` knows, each a helper of :mod:`fxc_env.core.validation`.
CHECK_KINDS = ("choice", "integer", "real", "probability", "seed", "boolean")
#: What argparse turns a flag's text into; ``"numbers"``: a number or comma-separated numbers.
FLAG_KINDS = ("str", "int", "float", "numbers")


@dataclass(frozen=True)
class Flag:
    """How an argument is written on the ``fxc simulate`` / ``fxc evaluate`` command line.

    The flag is ``--`` and the argument's name with dashes (``--n-agents``); left out, it
    keeps the scenario's value.
    """

    #: One of :data:`FLAG_KINDS`: argparse's ``type`` (``str``, ``int``, ``float``), or
    #: ``"numbers"`` for ``1.5`` or ``1.5,3`` (a range or a set, parsed by the flags module).
    kind: str = "str"
    #: The values argparse accepts (None: any); defaults to the argument's choices.
    choices: tuple[str, ...] | None = None
    #: The flag's help when it differs from the argument's one-line help.
    help: str | None = None


@dataclass(frozen=True)
class Argument:
    """One argument of the environment: everything the signatures, checks, flags and cards say of it."""

    #: The keyword, as every signature spells it.
    name: str
    #: Its type as the signatures write it (a string: the package postpones annotations).
    annotation: str
    #: The signature's default (:data:`REQUIRED` when there is none). ``None`` usually means
    #: "not given": the scenario's value, else :attr:`fallback`, applies.
    default: Any
    #: One line: the flag's ``--help`` text.
    help: str
    #: The card's "meaning" column (reST inline markup; a literal ``|`` is written ``\\|``).
    card: str
    #: How :meth:`check` validates a single value (one of :data:`CHECK_KINDS`), or ``""``
    #: when a helper of its own checks it (structured values, ranges known only with the graph).
    kind: str = ""
    #: The allowed values of a ``"choice"`` argument.
    choices: tuple[str, ...] | None = None
    #: Bounds of an ``"integer"`` or ``"real"`` argument (inclusive; None: unbounded).
    minimum: float | None = None
    maximum: float | None = None
    #: A ``"real"`` argument must be > 0.
    positive: bool = False
    #: The value ``make_config`` uses when neither the call nor the scenario gives one
    #: (the card's ``[value]``); :data:`NO_FALLBACK` when there is none.
    fallback: Any = NO_FALLBACK
    #: Whether a named scenario may set it (:data:`fxc_env.SCENARIOS`).
    from_scenario: bool = False
    #: The card's "type" column when the annotation (or the choices) would not say it well.
    card_type: str | None = None
    #: The card's "default" column when it is not the default or the fallback.
    card_default: str | None = None
    #: Its command-line flag, or None when the command line has none.
    flag: Flag | None = None

    def check(self, value: Any) -> Any:
        """``value`` checked by the :mod:`fxc_env.core.validation` helper of :attr:`kind` (its message on error).

        ``None`` passes when it is the default (it means "not given").
        """
        if value is None and self.default is None:
            return None
        if self.kind == "choice":
            return validation.choice(self.name, value, self.choices or ())
        if self.kind == "integer":
            return validation.integer(self.name, value, _optional_int(self.minimum), _optional_int(self.maximum))
        if self.kind == "real":
            return validation.real(self.name, value, self.minimum, self.maximum, positive=self.positive)
        if self.kind == "probability":
            return validation.probability(self.name, value)
        if self.kind == "seed":
            return validation.optional_seed(self.name, value)
        if self.kind == "boolean":
            if not isinstance(value, bool | np.bool_):
                raise validation.ArgumentTypeError(f"{self.name}: expected True or False, got {value!r}")
            return bool(value)
        raise TypeError(f"{self.name}: checked by a helper of its own, not by Argument.check")

    @property
    def flag_name(self) -> str:
        """``--name-with-dashes``."""
        return "--" + self.name.replace("_", "-")

    @property
    def card_row(self) -> str:
        """The argument's row of a card's Arguments table."""
        return f"| ``{self.name}`` | {self._card_type()} | {self._card_default()} | {self.card} |"

    def _card_type(self) -> str:
        if self.card_type is not None:
            return self.card_type
        if self.kind == "choice" and self.choices:
            options = " \\| ".join(f'"{option}"' for option in self.choices)
            return f"``None \\| {options}``" if self.default is None else f"``{options}``"
        return "``" + self.annotation.replace("|", "\\|") + "``"

    def _card_default(self) -> str:
        if self.card_default is not None:
            return self.card_default
        if self.fallback is not NO_FALLBACK:
            return f"[{_default_text(self.fallback)}]"
        return "required" if self.default is REQUIRED else _default_text(self.default)


def _optional_int(value: float | None) -> int | None:
    return None if value is None else int(value)


def _default_text(value: Any) -> str:
    return f'``"{value}"``' if isinstance(value, str) else repr(value)


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
    ("plan", "raw"): 1.0e3,
    ("residual", "raw"): 1.0e3,
    ("accel", "raw"): 1.0e9,
}

RENDER_MODES = ("human", "rgb_array")

#: The arguments of :func:`fxc_env.make_config`, in its signature's order (``scenario`` first,
#: positional; every other one keyword-only).
ENV_ARGUMENTS: tuple[Argument, ...] = (
    Argument(
        "scenario",
        "str | None",
        None,
        help="named scenario or 'none' (the defaults)",
        card='named preset from ``fxc_env.SCENARIOS`` (e.g. ``"paper_fig1"``, the paper\'s example)',
        flag=Flag(),
    ),
    Argument(
        "n_agents",
        "int | None",
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
    Argument(
        "topology",
        "Any",
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
    Argument(
        "settling_time",
        "float | None",
        None,
        help="deadline T_s in seconds",
        card="the deadline ``T_s`` (s)",
        fallback=20.0,
        from_scenario=True,
        flag=Flag("float"),
    ),
    Argument(
        "n_intervals",
        "int | None",
        None,
        help="number of sampling intervals K",
        card="K, the number of sampling intervals (of a named schedule)",
        fallback=200,
        from_scenario=True,
        flag=Flag("int"),
    ),
    Argument(
        "schedule",
        "Any",
        None,
        help="sampling schedule",
        card="the sampling instants (``T_k = 6 T_s / (pi k)^2``, last interval ending at ``T_s``)",
        fallback="paper",
        from_scenario=True,
        card_type="``" + " \\| ".join(f'"{name}"' for name in SCHEDULE_NAMES) + "`` or interval lengths",
        flag=Flag(choices=SCHEDULE_NAMES),
    ),
    Argument(
        "dim",
        "int | None",
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
    Argument(
        "action_mode",
        "str",
        "plan",
        help="what an action is: a planned terminal change (plan, default), the input at both ends (accel) "
        "or a correction added to the paper's plan (residual: the zero action is the reference)",
        card="meaning of an action (Action Space)",
        kind="choice",
        choices=("plan", "accel", "residual"),
        flag=Flag(),
    ),
    Argument(
        "obs_mode",
        "str",
        "normalized",
        help="scale-free (normalized, default) or physical (raw) observations and actions",
        card="scale-free or physical observations and actions",
        kind="choice",
        choices=("normalized", "raw"),
        flag=Flag(),
    ),
    Argument(
        "obs_format",
        "str",
        "flat",
        help="one Box per agent (flat, default) or a dict of neighbours, mask and clock",
        card='one Box, or ``{"neighbours", "mask", "clock"}``',
        kind="choice",
        choices=("flat", "dict"),
    ),
    Argument(
        "obs_dtype",
        "str",
        "float64",
        help="dtype of observations, their spaces and the normalized global state",
        card="dtype of observations, their spaces and the normalized global state",
        kind="choice",
        choices=("float64", "float32"),
    ),
    Argument(
        "global_state",
        "str",
        "raw",
        help="what state() returns: absolute rows (raw, default) or the scale-free vector (normalized)",
        card="what ``state()`` returns (State)",
        kind="choice",
        choices=("raw", "normalized"),
    ),
    Argument(
        "action_bound",
        "float | None",
        None,
        help="half-width b of the action Box (default: by action_mode and obs_mode)",
        card="half-width ``b`` of the action Box (default: the Action Space table's, by ``action_mode`` and "
        "``obs_mode``)",
        kind="real",
        positive=True,
        card_default="by mode",
    ),
    Argument(
        "reward_floor",
        "float",
        1e-12,
        help="f / D(0), the floor in the log reward (at most 1: a floor above D(0) leaves every reward 0)",
        card="``f / D(0)`` in the reward, in (0, 1]",
        kind="real",
        maximum=1.0,
        positive=True,
    ),
    Argument(
        "initial_state",
        "Any",
        None,
        help="a fixed initial state (x0, v0), or 'random' to drop the scenario's",
        card='fixed initial state ``(N, dim)`` arrays; ``"random"`` drops the scenario\'s',
        from_scenario=True,
        card_type='``None \\| "random" \\| (x0, v0)``',
        card_default="[random]",
    ),
    Argument(
        "position_range",
        "float | tuple[float, float] | None",
        None,
        help="initial positions U(-r, r) m; LOW,HIGH draws r log-uniformly",
        card="initial positions ``U(-r, r)`` (m); a pair draws ``r`` log-uniformly per episode",
        fallback=5.0,
        from_scenario=True,
        card_type="``float \\| (low, high) \\| None``",
        flag=Flag("numbers"),
    ),
    Argument(
        "velocity_range",
        "float | tuple[float, float] | None",
        None,
        help="initial velocities U(-r, r) m/s; LOW,HIGH as above",
        card="initial velocities ``U(-r, r)`` (m/s); a pair as above",
        fallback=2.0,
        from_scenario=True,
        card_type="``float \\| (low, high) \\| None``",
        flag=Flag("numbers"),
    ),
    Argument(
        "topology_seed",
        "int | None",
        0,
        help="seed of the random topology (default 0)",
        card='seed of ``topology="random"`` (of a family: the draw ``config.topology`` shows)',
        kind="seed",
        flag=Flag("int"),
    ),
    Argument(
        "mean_in_degree",
        "float | None",
        None,
        help="mean in-degree of random digraphs; LOW,HIGH draws it with --family",
        card='mean in-degree of ``"random"``',
        fallback=2.0,
        from_scenario=True,
        flag=Flag("numbers"),
    ),
    Argument(
        "topology_period",
        "int | None",
        None,
        help="graphs per switching period (random, or LOW,HIGH with --family)",
        card='number of switching graphs of ``"random"``',
        fallback=1,
        from_scenario=True,
        flag=Flag("numbers"),
    ),
    Argument(
        "obs_slots",
        "int | None",
        None,
        help="neighbour rows of the observation (a learned policy's width)",
        card="neighbour rows in an observation (at least ``d_max``, at most N)",
        from_scenario=True,
        card_default="``d_max``",
        flag=Flag("int"),
    ),
    Argument(
        "u_max",
        "float | Sequence[float] | None",
        None,
        help="input limit (m/s^2); A,B,C draws one per episode",
        card="clips each input component to ``±u_max`` m/s^2, integrated exactly (infos report the saturated "
        "share); a set draws one limit per episode",
        from_scenario=True,
        card_type="``float \\| set of floats \\| None``",
        flag=Flag("numbers"),
    ),
    Argument(
        "obs_noise",
        "float",
        0.0,
        help="standard deviation of measurement noise (m, m/s)",
        card="standard deviation of Gaussian noise (m, m/s) on each relative measurement",
        kind="real",
        minimum=0.0,
        maximum=validation.STATE_LIMIT,
        flag=Flag("float"),
    ),
    Argument(
        "link_dropout",
        "float",
        0.0,
        help="probability that an edge is lost at a sampling instant",
        card="probability in [0, 1) that an edge is lost at a sampling instant (the mask shows it)",
        kind="probability",
        flag=Flag("float"),
    ),
    Argument(
        "switching",
        "str",
        "periodic",
        help="cycle through the graphs (periodic, default) or draw each interval's graph (random)",
        card="cycle through the graphs, or draw each interval's graph",
        kind="choice",
        choices=("periodic", "random"),
        flag=Flag(),
    ),
    Argument(
        "agent_model",
        "Any",
        None,
        help="the agents' dynamics per axis (default double_integrator; README, 'Agent models')",
        card='the agents\' model per axis: a name, ``"single_integrator"``, ``"integrator_chain"``, ``"damped"``, '
        '``"oscillator"``, a dict with its parameter (``{"name": "damped", "damping": 0.5}``: ``order`` 1-4, '
        '``damping`` c in 1/s, ``frequency`` ω in rad/s), or a controllable pair ``(A, B)`` (README, "Agent models")',
        fallback="double_integrator",
        from_scenario=True,
        card_type="name, dict or ``(A, B)``",
        flag=Flag(choices=MODEL_NAMES),
    ),
    Argument(
        "order",
        "int | None",
        None,
        help="order of --agent-model integrator_chain (1-4, default 2)",
        card='deprecated: ``agent_model={"name": "integrator_chain", "order": n}`` (1-4)',
        from_scenario=True,
        card_default="2",
        flag=Flag("int"),
    ),
    Argument(
        "damping",
        "float | None",
        None,
        help=f"drag c of --agent-model damped (1/s, default {DEFAULT_DAMPING:g})",
        card='deprecated: ``agent_model={"name": "damped", "damping": c}`` (1/s)',
        from_scenario=True,
        card_default=repr(DEFAULT_DAMPING),
        flag=Flag("float"),
    ),
    Argument(
        "frequency",
        "float | None",
        None,
        help=f"frequency of --agent-model oscillator (rad/s, default {DEFAULT_FREQUENCY:g})",
        card='deprecated: ``agent_model={"name": "oscillator", "frequency": omega}`` (rad/s)',
        from_scenario=True,
        card_default=repr(DEFAULT_FREQUENCY),
        flag=Flag("float"),
    ),
    Argument(
        "formation_offsets",
        "Any",
        None,
        help="formation offsets h_i: positions (N, dim) or full states (N, dim, n)",
        card='agents agree on ``z_i - e^{A t} h_i``: position offsets hold a formation (README, "Formations")',
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
#: The graph as edge tensors for graph neural networks (README, "Graph tensors"): taken by the
#: TorchRL environment (root keys) and the PettingZoo parallel env (per-step infos) only.
GRAPH_TENSORS = Argument(
    "graph_tensors",
    "bool",
    False,
    help="add the current graph as edge_index / edge_mask / n_edges / edge_attr",
    card="the current interval's graph as PyG-style edge tensors, ``edge_index`` (source j, target i) and "
    '``edge_attr`` (the observation\'s rows ``z_j - z_i``) (README, "Graph tensors")',
    kind="boolean",
)

#: The keywords of :func:`fxc_env.make_config`, in order.
ENV_ARGUMENT_NAMES: tuple[str, ...] = tuple(argument.name for argument in ENV_ARGUMENTS)
#: Every argument above by name.
ARGUMENTS: Mapping[str, Argument] = MappingProxyType(
    {argument.name: argument for argument in (*ENV_ARGUMENTS, *FRONT_END_ARGUMENTS)}
)


def env_arguments(namespace: Mapping[str, Any]) -> dict[str, Any]:
    """The :func:`fxc_env.make_config` keywords out of a front end's ``locals()`` (every one, in order)."""
    return {name: namespace[name] for name in ENV_ARGUMENT_NAMES}


def arguments_table(arguments: Iterable[Argument]) -> str:
    """A card's Arguments table: the header, then one :attr:`Argument.card_row` per argument."""
    rows = [argument.card_row for argument in arguments]
    return "\n".join(["| parameter | type | default | meaning |", "|-----------|------|---------|---------|", *rows])


#: The line a card's docstring holds where :func:`with_arguments_table` puts the table.
TABLE_MARKER = "{arguments table}"


def with_arguments_table(doc: str | None, arguments: Sequence[Argument]) -> str:
    """``doc`` with its :data:`TABLE_MARKER` line replaced by the table of ``arguments``, at that line's indent."""
    lines = (doc or "").split("\n")
    marked = [i for i, line in enumerate(lines) if line.strip() == TABLE_MARKER]
    if len(marked) != 1:
        raise ValueError(
            f"with_arguments_table: expected one {TABLE_MARKER!r} line in the docstring, got {len(marked)}"
        )
    line = lines[marked[0]]
    indent = line[: len(line) - len(line.lstrip())]
    table = [indent + row for row in arguments_table(arguments).split("\n")]
    return "\n".join([*lines[: marked[0]], *table, *lines[marked[0] + 1 :]])
