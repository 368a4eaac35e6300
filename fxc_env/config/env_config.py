"""Validated environment settings: :func:`make_config` turns keyword arguments into an :class:`EnvConfig`.

The engine, the PettingZoo environment, the SB3 VecEnv and the policies all read the same
immutable config. The arguments, their defaults and allowed values are the table of
:mod:`fxc_env.config.arguments`. Every argument is checked by :mod:`fxc_env.core.validation`,
so a bad one raises an :class:`~fxc_env.core.validation.ArgumentError` that names it. Named
scenarios (:mod:`fxc_env.config.scenarios`) are frozen presets that explicit arguments override.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Unpack

import numpy as np

from fxc_env.config.arguments import (
    ARGUMENTS,
    DEFAULT_ACTION_BOUNDS,
    ENV_ARGUMENTS,
    MAX_CYCLES,
    NO_FALLBACK,
    RENDER_MODE,
    RENDER_MODES,
    EnvKwargs,
    env_arguments,
    env_signature,
)
from fxc_env.config.layout import CLOCK_SIZE, ObservationLayout
from fxc_env.config.scenarios import scenario_preset
from fxc_env.core import validation
from fxc_env.core.families import AnyFamily, is_family_spec, make_family
from fxc_env.core.graphs import Topology, make_topology
from fxc_env.core.linear import (
    IntervalMaps,
    LinearModel,
    check_horizon,
    formation_offsets,
    model_matrices,
    warn_if_unstable,
)
from fxc_env.core.models import FLAT_PARAMETERS, MODEL_PARAMETERS, model_spec
from fxc_env.core.schedules import Schedule, make_schedule
from fxc_env.core.validation import ArgumentError, ArgumentTypeError

__all__ = [
    "CLOCK_SIZE",
    "DEFAULT_ACTION_BOUNDS",
    "RENDER_MODES",
    "EnvConfig",
    "ObservationLayout",
    "config_of",
    "make_config",
]


@dataclass(frozen=True, eq=False)
class EnvConfig:
    """Everything that defines an episode family. Build it with :func:`make_config`."""

    topology: Topology
    family: AnyFamily | None
    schedule: Schedule
    dim: int
    obs_slots: int
    action_mode: str
    obs_mode: str
    obs_format: str
    obs_dtype: str
    global_state: str
    action_bound: float
    reward_floor: float
    initial_state: tuple[np.ndarray, np.ndarray] | None
    position_range: tuple[float, float]
    velocity_range: tuple[float, float]
    u_max_choices: tuple[float, ...] | None
    obs_noise: float
    link_dropout: float
    switching: str
    scenario: str | None
    #: The agents' per-axis linear model, or None for the double integrator's closed forms.
    model: LinearModel | None = None
    #: ``"double_integrator"``, a named model of :data:`fxc_env.core.linear.MODEL_NAMES` or ``"linear"`` (a given (A, B)).
    agent_model: str = "double_integrator"
    #: Formation offsets ``h_i`` as full states ``(N, n, dim)``, or None (plain consensus).
    formation: np.ndarray | None = None
    #: The measurement quantum (m, m/s) rows are rounded to; 0: exact rows (``obs_resolution=None``).
    obs_resolution: float = 0.0

    @property
    def n_states(self) -> int:
        """n, the state size per axis: 2 (position, velocity) for the double integrator."""
        return 2 if self.model is None else self.model.n_states

    @property
    def n_inputs(self) -> int:
        """m, the inputs per axis: 1 for the double integrator."""
        return 1 if self.model is None else self.model.n_inputs

    @cached_property
    def interval_maps(self) -> IntervalMaps | None:
        """Free motion and minimum-energy steering of every interval of the schedule (general models only)."""
        return None if self.model is None else self.model.interval_maps(self.schedule.intervals)

    @cached_property
    def row_scales(self) -> np.ndarray:
        """Per sampling instant, what each state component is multiplied by to read in position units: ``(K + 1, n)``.

        The double integrator: ``[1, T_{k+1}]`` (``x`` and ``T v``, the normalized units of
        docs: environment.md, "Observation"); with ``action_mode="plan_balanced"`` ``[1, T_s]``
        (:attr:`velocity_weight`: velocities weighed as ``D = e_x + T_s e_v`` weighs them). A general model: ``D_0 / D_l`` with the time-scaled frame ``D = h^levels``
        (:mod:`fxc_env.core.linear`), e.g. ``[1, T, T^2]`` for a chain of order 3. The
        instant ``K`` repeats the last interval's row.
        """
        k_all = np.arange(self.n_intervals + 1)
        last = np.minimum(k_all, self.n_intervals - 1)
        if self.model is None:
            weight = self.velocity_weight
            velocity = self.schedule.intervals[last] if weight is None else np.full(len(k_all), weight)
            return np.stack([np.ones(len(k_all)), velocity], axis=1)
        scale = self.interval_maps.scale[last]
        return scale[:, :1] / scale

    @property
    def velocity_weight(self) -> float | None:
        """``T_s`` (s) with ``action_mode="plan_balanced"``, else None (velocities weighed by the interval ``T_{k+1}``).

        What the local scale ``s_i = max(|x_j - x_i|, W |v_j - v_i|)``, the observation's
        velocity rows ``W (v_j - v_i) / s_i`` and the action's velocity unit ``s_i / W``
        weigh velocities by (docs: environment.md, "Conditioning of the action").
        """
        return self.schedule.settling_time if self.action_mode == "plan_balanced" else None

    @cached_property
    def formation_motion(self) -> np.ndarray | None:
        """``e^{A t_k}`` at every sampling instant ``(K + 1, n, n)`` when there are formation offsets, else None."""
        return None if self.formation is None else self.free_motion(self.schedule.times)

    def free_motion(self, times: Any) -> np.ndarray:
        """``e^{A t}`` at ``times`` (s), ``(P, n, n)``: the agents' free motion (the double integrator's without a model)."""
        model = self.model if self.model is not None else LinearModel(*model_matrices("double_integrator"))
        return model.free_motion_matrix(times)

    @property
    def n_agents(self) -> int:
        return self.topology.n_agents

    @property
    def settling_time(self) -> float:
        return self.schedule.settling_time

    @property
    def n_intervals(self) -> int:
        return self.schedule.n_intervals

    @cached_property
    def layout(self) -> ObservationLayout:
        return ObservationLayout(
            self.obs_slots, self.dim, limit_feature=self.u_max_choices is not None, n_states=self.n_states
        )

    @property
    def u_max(self) -> float | None:
        """The input limit (m/s^2) when it is one number; None without a limit or when drawn per episode."""
        choices = self.u_max_choices
        return choices[0] if choices is not None and len(choices) == 1 else None

    @property
    def action_size(self) -> int:
        return self.n_states * self.dim

    @property
    def state_limit(self) -> float:
        """Largest accepted position or velocity magnitude (m, m/s): float32's range for raw float32 observations."""
        raw32 = (self.obs_dtype, self.obs_mode) == ("float32", "raw")
        return validation.FLOAT32_STATE_LIMIT if raw32 else validation.STATE_LIMIT

    @property
    def observation_dtype(self) -> type[np.floating]:
        """numpy dtype of observations (and of the normalized global state)."""
        return np.float32 if self.obs_dtype == "float32" else np.float64


def check_render_mode(render_mode: Any) -> str | None:
    """``render_mode`` if it is None or one of :data:`RENDER_MODES`."""
    return RENDER_MODE.check(render_mode)


def check_max_cycles(max_cycles: Any) -> int | None:
    """``max_cycles`` if it is None or an integer >= 1."""
    return MAX_CYCLES.check(max_cycles)


def config_of(source: Any, who: str = "policy") -> EnvConfig:
    """The :class:`EnvConfig` of an environment (parallel, AEC, VecEnv, wrapped) or the config itself."""
    if isinstance(source, EnvConfig):
        return source
    for candidate in (source, getattr(source, "unwrapped", None), getattr(source, "venv", None)):
        config = getattr(candidate, "config", None)
        if isinstance(config, EnvConfig):
            return config
    raise ArgumentTypeError(
        f"{who}: expected an fxc_env environment (parallel, AEC or VecEnv) or an EnvConfig, got {type(source).__name__}"
    )


def _merged_settings(scenario: str | None, given: dict[str, Any], initial_state: Any) -> dict[str, Any]:
    """The scenario's preset overridden by the arguments given (not None), with defaults filled in.

    A preset's fixed initial state is dropped when ``n_agents`` or ``dim`` is overridden
    (it has the scenario's shape) or when ``initial_state="random"``.
    """
    merged = scenario_preset(scenario)
    for name in ("n_agents", "dim"):  # checked first: they are compared with the preset's below
        if given[name] is not None:
            given[name] = ARGUMENTS[name].check(given[name])
    preset_shape = {"n_agents": merged.get("n_agents"), "dim": merged.get("dim", 1)}
    resized = any(given[k] is not None and given[k] != preset_shape[k] for k in preset_shape)
    if resized and initial_state is None:
        merged.pop("initial_state", None)
    merged.update({k: v for k, v in given.items() if v is not None})
    if isinstance(initial_state, str):
        if initial_state != "random":
            raise ArgumentError(f"initial_state: expected None, 'random' or a pair (x0, v0), got {initial_state!r}")
        merged.pop("initial_state")
    for argument in ENV_ARGUMENTS:
        if argument.fallback is not NO_FALLBACK and argument.name not in _CONDITIONAL_FALLBACKS:
            merged.setdefault(argument.name, argument.fallback)
    if isinstance(merged["schedule"], str):
        merged.setdefault("n_intervals", ARGUMENTS["n_intervals"].fallback)
    return merged


#: Fallbacks that apply only sometimes: K to a named schedule (interval lengths set K), N to a
#: named topology or a family (an edge list or a graph sets N).
_CONDITIONAL_FALLBACKS = ("n_intervals", "n_agents")


#: The arguments a named scenario may set (the others keep their defaults unless given).
_FROM_SCENARIO = tuple(argument.name for argument in ENV_ARGUMENTS if argument.from_scenario)


def _initial_state(
    value: Any, n_agents: int, dim: int, limit: float = validation.STATE_LIMIT
) -> tuple[np.ndarray, np.ndarray] | None:
    if value is None:
        return None
    if isinstance(value, str | bytes) or not isinstance(value, tuple | list) or len(value) != 2:
        raise ArgumentError(f"initial_state: expected a pair (x0, v0) of arrays of shape ({n_agents}, {dim})")
    return (
        validation.state_array("initial_state[0] (x0)", value[0], n_agents, dim, limit),
        validation.state_array("initial_state[1] (v0)", value[1], n_agents, dim, limit),
    )


def _obs_slots(value: Any, topology: Topology, family: AnyFamily | None) -> int:
    largest = topology.max_in_degree if family is None else family.max_in_degree(topology.n_agents)
    if value is None:
        return largest
    slots = validation.integer("obs_slots", value, 1, max(topology.n_agents, 1))
    if slots < largest:
        what = "the topology has" if family is None else "the family's draws have"
        raise ArgumentError(f"obs_slots: {what} in-degree up to {largest}; expected at least that, got {value!r}")
    return slots


def _scale_range(name: str, value: Any, limit: float = validation.STATE_LIMIT) -> tuple[float, float]:
    """A half-width (m or m/s) or a ``(low, high)`` range of half-widths drawn log-uniformly per episode.

    ``limit`` is :data:`~fxc_env.core.validation.FLOAT32_STATE_LIMIT` for raw float32 observations.
    """
    if isinstance(value, tuple | list):
        if len(value) != 2:
            raise ArgumentError(f"{name}: expected a number or a (low, high) pair, got {value!r}")
        low, high = (_half_width(name, v, limit) for v in value)
        if low > high:
            raise ArgumentError(f"{name}: expected low <= high, got {value!r}")
        return low, high
    number = _half_width(name, value, limit)
    return number, number


def _noise(value: float, limit: float, name: str = "obs_noise") -> float:
    """``obs_noise`` (or ``obs_resolution``), at most ``limit`` (with raw float32 observations, a row beyond float32's range would observe as inf)."""
    if value > limit:
        raise ArgumentError(
            f'{name}: expected a number in [0, {limit:g}] (float32 range with obs_dtype="float32", obs_mode="raw"), '
            f"got {value!r}"
        )
    return value


def _half_width(name: str, value: Any, limit: float) -> float:
    number = validation.real(name, value, positive=True)
    if number > limit:
        raise ArgumentError(
            f"{name}: expected a positive finite number <= {limit:g}, got {value!r}"
            + ("" if limit == validation.STATE_LIMIT else ' (float32 range with obs_dtype="float32", obs_mode="raw")')
        )
    return number


def _check_random_only(given: dict[str, Any], topology: Any) -> None:
    """``mean_in_degree`` and ``topology_period`` shape only ``topology="random"``: refuse them elsewhere."""
    if isinstance(topology, str) and topology == "random":
        return
    shown = repr(topology) if isinstance(topology, str) else type(topology).__name__
    for name in ("mean_in_degree", "topology_period"):
        if given[name] is not None:
            raise ArgumentError(
                f"{name}: applies to topology='random' only (a family takes it in its spec), got topology {shown}"
            )


def _input_limits(value: Any) -> tuple[float, ...] | None:
    """``u_max``: None, one limit, or a set of limits drawn uniformly per episode (m/s^2)."""
    if value is None:
        return None
    if isinstance(value, tuple | list | set | frozenset):
        if not value:
            raise ArgumentError("u_max: expected a number or a non-empty set of numbers, got an empty one")
        return tuple(sorted(validation.real("u_max", v, maximum=validation.STATE_LIMIT, positive=True) for v in value))
    return (validation.real("u_max", value, maximum=validation.STATE_LIMIT, positive=True),)


def _topology(merged: dict[str, Any], topology_seed: Any) -> tuple[Topology, AnyFamily | None]:
    """The fixed topology, or for a family its draw from ``topology_seed`` (shown in tables) and the family."""
    spec = merged["topology"]
    if isinstance(spec, np.ndarray) and spec.ndim < 2:  # an edge list is (E, 2); a 0-d or 1-d array is none
        raise ArgumentTypeError(
            f"topology: expected a name, an edge list of (j, i) pairs, a list of edge lists, a family or networkx "
            f"DiGraph(s); got an array of shape {spec.shape}"
        )
    if is_family_spec(spec):
        family = make_family(spec)
        n_agents = ARGUMENTS["n_agents"].check(merged.get("n_agents", ARGUMENTS["n_agents"].fallback))
        seed = ARGUMENTS["topology_seed"].check(topology_seed)
        return family.draw(n_agents, np.random.default_rng(seed)), family
    topology = make_topology(
        spec,
        merged.get("n_agents"),
        seed=topology_seed,
        mean_in_degree=merged["mean_in_degree"],
        period=merged["topology_period"],
    )
    if topology.n_agents < validation.MIN_AGENTS:  # a graph or Topology of one node (n_agents was checked)
        raise ArgumentError(
            f"topology: expected at least {validation.MIN_AGENTS} agents (consensus is agreement between agents), "
            f"got a graph of {topology.n_agents}"
        )
    return topology, None


@env_signature(returns="EnvConfig")
def make_config(scenario: str | None = None, **kwargs: Unpack[EnvKwargs]) -> EnvConfig:
    """Validate the environment's keyword arguments (a scenario's preset first, explicit ones win).

    The arguments, their types, defaults, allowed values and meanings are the table
    :data:`fxc_env.config.arguments.ENV_ARGUMENTS`, shown as every card's Arguments table
    (``help(fxc_env.parallel_env)``). Arguments left at None take the scenario's value, else
    the table's fallback (the card's ``[value]``). A topology family's ``config.topology`` is
    its draw from ``topology_seed``.

    Raises:
        ArgumentError: naming the first bad argument and what was expected (a ``TypeError``
            too for a wrong type).
    """
    arguments = env_arguments({"scenario": scenario}, kwargs)
    given = {name: arguments[name] for name in _FROM_SCENARIO}
    merged = _merged_settings(scenario, given, arguments["initial_state"])
    _check_random_only(given, merged["topology"])
    config = _validated(merged, arguments)
    if config.model is not None:
        _check_steering(config, merged)
        warn_if_unstable(config.model, config.settling_time)
    return config


def _validated(merged: dict[str, Any], arguments: dict[str, Any]) -> EnvConfig:
    """The :class:`EnvConfig` of the merged settings and the other arguments, each checked."""

    def checked(name: str) -> Any:
        return ARGUMENTS[name].check(arguments[name])

    dim_value = ARGUMENTS["dim"].check(merged["dim"])
    topo, family = _topology(merged, arguments["topology_seed"])
    sched = make_schedule(merged["settling_time"], merged.get("n_intervals"), merged["schedule"])
    action_mode, obs_mode = checked("action_mode"), checked("obs_mode")
    bound = checked("action_bound")
    if bound is None:
        bound = DEFAULT_ACTION_BOUNDS[(action_mode, obs_mode)]
    model_name, model = _agent_model(merged, arguments)
    u_max_choices = _input_limits(merged.get("u_max"))
    if model is not None:
        _check_model_modes(model_name, model, sched.settling_time, action_mode, u_max_choices)
    n_states = 2 if model is None else model.n_states
    formation = _formation(merged.get("formation_offsets"), topo.n_agents, dim_value, n_states)
    dtype = checked("obs_dtype")
    limit = validation.FLOAT32_STATE_LIMIT if (dtype, obs_mode) == ("float32", "raw") else validation.STATE_LIMIT
    return EnvConfig(
        topology=topo,
        family=family,
        schedule=sched,
        dim=dim_value,
        obs_slots=_obs_slots(merged.get("obs_slots"), topo, family),
        action_mode=action_mode,
        obs_mode=obs_mode,
        obs_format=checked("obs_format"),
        obs_dtype=dtype,
        global_state=checked("global_state"),
        action_bound=bound,
        reward_floor=checked("reward_floor"),
        initial_state=_initial_state(merged.get("initial_state"), topo.n_agents, dim_value, limit),
        position_range=_scale_range("position_range", merged["position_range"], limit),
        velocity_range=_scale_range("velocity_range", merged["velocity_range"], limit),
        u_max_choices=u_max_choices,
        obs_noise=_noise(checked("obs_noise"), limit),
        obs_resolution=_noise(checked("obs_resolution") or 0.0, limit, "obs_resolution"),
        link_dropout=checked("link_dropout"),
        switching=checked("switching"),
        scenario=arguments["scenario"],
        model=model,
        agent_model=model_name,
        formation=formation,
    )


def _check_model_modes(name: str, model: LinearModel, settling_time: float, action_mode: str, u_max: Any) -> None:
    """A general model's horizon, and the double integrator's own options refused for it."""
    check_horizon(model, settling_time)
    if action_mode != "plan":
        raise ArgumentError(
            f"action_mode: {name!r} agents take plans only (the minimum-energy input); "
            f"{action_mode!r} is the double integrator's"
        )
    if u_max is not None:
        raise ArgumentError(f"u_max: input limits are integrated exactly for the double integrator only, not {name!r}")


def _check_steering(config: EnvConfig, merged: dict[str, Any]) -> None:
    """Build the model's interval maps now, blaming the model's parameter when they cannot be built.

    A parameter far outside the physical range (``frequency=2**70``) leaves the controllability
    Gramian of the schedule's intervals singular in float64; the maps' own message names
    ``intervals``, which the user did not give, so the model's parameter is named instead.
    """
    try:
        config.interval_maps  # noqa: B018 (cached on the config: the engine reads it)
    except ArgumentError as error:
        steered = f"with which {config.agent_model!r} agents can be steered over every sampling interval"
        raise _blamed(error, merged["agent_parameters"], steered) from None


def _agent_model(merged: dict[str, Any], arguments: dict[str, Any]) -> tuple[str, LinearModel | None]:
    """``(name, model)``: None for the double integrator's closed forms, else the validated model."""
    name, parameters = model_spec(merged.get("agent_model"), {key: arguments.get(key) for key in FLAT_PARAMETERS})
    merged["agent_parameters"] = parameters
    if name == "double_integrator":
        return name, None
    if name == "linear":
        return name, LinearModel(parameters["A"], parameters["B"])
    try:
        return name, LinearModel.named(name, **parameters)
    except ArgumentError as error:  # a parameter that passes its own check can still break the matrices
        raise _blamed(error, parameters, f"that gives {name!r} finite, controllable matrices") from None


def _blamed(error: ArgumentError, parameters: dict[str, Any], expected: str) -> ArgumentError:
    """``error`` of a model built from ``parameters`` named after them (the user gave those, not what failed)."""
    named = [key for key in MODEL_PARAMETERS.values() if key in parameters]
    if not named or str(error).startswith(tuple(named)):
        return error
    shown = ", ".join(f"{key} = {parameters[key]!r}" for key in named)
    return ArgumentError(f"{'/'.join(named)}: expected a value {expected}; {shown} gives {error}")


def _formation(value: Any, n_agents: int, dim: int, n_states: int) -> np.ndarray | None:
    """Formation offsets as full states in the engine's layout ``(N, n, dim)``, or None."""
    if value is None:
        return None
    offsets = formation_offsets(value, n_agents, dim, n_states)  # (N, dim, n), checked
    if np.max(np.abs(offsets), initial=0.0) > validation.STATE_LIMIT:
        raise ArgumentError(f"formation_offsets: expected entries within ±{validation.STATE_LIMIT:g}")
    return np.ascontiguousarray(np.swapaxes(offsets, 1, 2))
