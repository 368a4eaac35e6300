"""Validated environment settings: :func:`make_config` turns keyword arguments into an :class:`EnvConfig`.

The engine, the PettingZoo environment, the SB3 VecEnv and the policies all read the same
immutable config. Every argument is checked by :mod:`fxc_env.core.validation`, so a bad one
raises an :class:`~fxc_env.core.validation.ArgumentError` that names it. Named scenarios
(:mod:`fxc_env.scenarios`) are frozen presets that explicit arguments override.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from fxc_env.core import validation
from fxc_env.core.families import AnyFamily, is_family_spec, make_family
from fxc_env.core.graphs import Topology, make_topology
from fxc_env.core.schedules import Schedule, make_schedule
from fxc_env.core.validation import ArgumentError, ArgumentTypeError
from fxc_env.layout import CLOCK_SIZE, ObservationLayout
from fxc_env.scenarios import scenario_preset

__all__ = ["CLOCK_SIZE", "EnvConfig", "ObservationLayout", "config_of", "make_config"]

ACTION_MODES = ("plan", "accel")
SWITCHING_MODES = ("periodic", "random")
OBS_MODES = ("normalized", "raw")
OBS_FORMATS = ("flat", "dict")
OBS_DTYPES = ("float64", "float32")
GLOBAL_STATES = ("raw", "normalized")
RENDER_MODES = ("human", "rgb_array")

#: Half-widths of the action Box per (action_mode, obs_mode). Normalised bounds hold the
#: reference for every state (its plan is at most 2 and 1, its accel ends at most 10 and 8).
#: Raw bounds are nominal: no fixed bound holds every graph and scale. They hold the
#: reference from the documented random initial ranges on every built-in topology up to
#: N = 100 (the slowest, a 100-ring, peaks near 4e7 m/s^2 in accel mode); pass
#: ``action_bound`` for larger or slower-mixing cases.
DEFAULT_ACTION_BOUNDS = {
    ("plan", "normalized"): 2.0,
    ("accel", "normalized"): 10.0,
    ("plan", "raw"): 1.0e3,
    ("accel", "raw"): 1.0e9,
}


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
        return ObservationLayout(self.obs_slots, self.dim, limit_feature=self.u_max_choices is not None)

    @property
    def u_max(self) -> float | None:
        """The input limit (m/s^2) when it is one number; None without a limit or when drawn per episode."""
        choices = self.u_max_choices
        return choices[0] if choices is not None and len(choices) == 1 else None

    @property
    def topology_name(self) -> str:
        """The family's name, or the fixed topology's."""
        return self.family.name if self.family is not None else self.topology.name

    @property
    def action_size(self) -> int:
        return 2 * self.dim

    @property
    def observation_dtype(self) -> type[np.floating]:
        """numpy dtype of observations (and of the normalized global state)."""
        return np.float32 if self.obs_dtype == "float32" else np.float64


def check_render_mode(render_mode: Any) -> str | None:
    """``render_mode`` if it is None or one of :data:`RENDER_MODES`."""
    return None if render_mode is None else validation.choice("render_mode", render_mode, RENDER_MODES)


def check_max_cycles(max_cycles: Any) -> int | None:
    """``max_cycles`` if it is None or an integer >= 1."""
    return None if max_cycles is None else validation.integer("max_cycles", max_cycles, 1)


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
    preset_shape = {"n_agents": merged.get("n_agents"), "dim": merged.get("dim", 1)}
    resized = any(given[k] is not None and given[k] != preset_shape[k] for k in preset_shape)
    if resized and initial_state is None:
        merged.pop("initial_state", None)
    merged.update({k: v for k, v in given.items() if v is not None})
    if isinstance(initial_state, str):
        if initial_state != "random":
            raise ArgumentError(f"initial_state: expected None, 'random' or a pair (x0, v0), got {initial_state!r}")
        merged.pop("initial_state")
    merged.setdefault("topology", "paper_fig1")
    merged.setdefault("settling_time", 20.0)
    merged.setdefault("schedule", "paper")
    merged.setdefault("dim", 1)
    merged.setdefault("position_range", 5.0)
    merged.setdefault("velocity_range", 2.0)
    if isinstance(merged["schedule"], str):
        merged.setdefault("n_intervals", 200)
    return merged


def _initial_state(value: Any, n_agents: int, dim: int) -> tuple[np.ndarray, np.ndarray] | None:
    if value is None:
        return None
    if isinstance(value, str | bytes) or not isinstance(value, tuple | list) or len(value) != 2:
        raise ArgumentError(f"initial_state: expected a pair (x0, v0) of arrays of shape ({n_agents}, {dim})")
    return (
        validation.state_array("initial_state[0] (x0)", value[0], n_agents, dim),
        validation.state_array("initial_state[1] (v0)", value[1], n_agents, dim),
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


def _scale_range(name: str, value: Any) -> tuple[float, float]:
    """A half-width (m or m/s) or a ``(low, high)`` range of half-widths drawn log-uniformly per episode."""
    if isinstance(value, tuple | list):
        if len(value) != 2:
            raise ArgumentError(f"{name}: expected a number or a (low, high) pair, got {value!r}")
        low, high = (validation.real(name, v, maximum=validation.STATE_LIMIT, positive=True) for v in value)
        if low > high:
            raise ArgumentError(f"{name}: expected low <= high, got {value!r}")
        return low, high
    number = validation.real(name, value, maximum=validation.STATE_LIMIT, positive=True)
    return number, number


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
    if is_family_spec(spec):
        family = make_family(spec)
        n_agents = validation.integer("n_agents", merged.get("n_agents", 6), 1, validation.MAX_AGENTS)
        seed = validation.optional_seed("topology_seed", topology_seed)
        return family.draw(n_agents, np.random.default_rng(seed)), family
    topology = make_topology(
        spec,
        merged.get("n_agents"),
        seed=topology_seed,
        mean_in_degree=merged.get("mean_in_degree", 2.0),
        period=merged.get("topology_period", 1),
    )
    return topology, None


def make_config(
    scenario: str | None = None,
    *,
    n_agents: int | None = None,
    topology: Any = None,
    settling_time: float | None = None,
    n_intervals: int | None = None,
    schedule: Any = None,
    dim: int | None = None,
    action_mode: str = "plan",
    obs_mode: str = "normalized",
    obs_format: str = "flat",
    obs_dtype: str = "float64",
    global_state: str = "raw",
    action_bound: float | None = None,
    reward_floor: float = 1e-12,
    initial_state: Any = None,
    position_range: float | tuple[float, float] | None = None,
    velocity_range: float | tuple[float, float] | None = None,
    topology_seed: int | None = 0,
    mean_in_degree: float | None = None,
    topology_period: int | None = None,
    obs_slots: int | None = None,
    u_max: float | Sequence[float] | None = None,
    obs_noise: float = 0.0,
    link_dropout: float = 0.0,
    switching: str = "periodic",
) -> EnvConfig:
    """Validate the environment's keyword arguments (a scenario's preset first, explicit ones win).

    The arguments are those of :class:`fxc_env.consensus_env.ConsensusParallelEnv` (its card
    has the table). ``topology`` may be a family (:func:`fxc_env.core.families.make_family`),
    drawn anew at every reset; ``config.topology`` is then its draw from ``topology_seed``.
    ``obs_slots`` pads the observation to at least that many neighbour rows (default: the
    largest in-degree of the topology or of any draw of the family). ``position_range`` and
    ``velocity_range`` (default 5 m and 2 m/s) are half-widths or ``(low, high)`` ranges
    drawn log-uniformly per episode. Arguments left at None take the scenario's value. Realism options are off by default: ``u_max`` clips every input component to
    ``[-u_max, u_max]`` m/s^2 (integrated exactly; a set of numbers is drawn per episode);
    ``obs_noise`` adds Gaussian noise of that standard deviation (m, m/s) to each relative
    measurement; ``link_dropout`` loses each edge at each sampling instant with that
    probability; ``switching="random"`` draws each interval's graph from the topology set.
    """
    given = {
        "n_agents": n_agents,
        "topology": topology,
        "settling_time": settling_time,
        "n_intervals": n_intervals,
        "schedule": schedule,
        "dim": dim,
        "initial_state": initial_state,
        "mean_in_degree": mean_in_degree,
        "topology_period": topology_period,
        "obs_slots": obs_slots,
        "position_range": position_range,
        "velocity_range": velocity_range,
        "u_max": u_max,
    }
    merged = _merged_settings(scenario, given, initial_state)
    dim_value = validation.integer("dim", merged["dim"], 1, validation.MAX_DIM)
    topo, family = _topology(merged, topology_seed)
    sched = make_schedule(merged["settling_time"], merged.get("n_intervals"), merged["schedule"])
    action_mode = validation.choice("action_mode", action_mode, ACTION_MODES)
    obs_mode = validation.choice("obs_mode", obs_mode, OBS_MODES)
    bound = (
        DEFAULT_ACTION_BOUNDS[(action_mode, obs_mode)]
        if action_bound is None
        else validation.real("action_bound", action_bound, positive=True)
    )
    return EnvConfig(
        topology=topo,
        family=family,
        schedule=sched,
        dim=dim_value,
        obs_slots=_obs_slots(merged.get("obs_slots"), topo, family),
        action_mode=action_mode,
        obs_mode=obs_mode,
        obs_format=validation.choice("obs_format", obs_format, OBS_FORMATS),
        obs_dtype=validation.choice("obs_dtype", obs_dtype, OBS_DTYPES),
        global_state=validation.choice("global_state", global_state, GLOBAL_STATES),
        action_bound=bound,
        reward_floor=validation.real("reward_floor", reward_floor, positive=True),
        initial_state=_initial_state(merged.get("initial_state"), topo.n_agents, dim_value),
        position_range=_scale_range("position_range", merged["position_range"]),
        velocity_range=_scale_range("velocity_range", merged["velocity_range"]),
        u_max_choices=_input_limits(merged.get("u_max")),
        obs_noise=validation.real("obs_noise", obs_noise, 0.0, validation.STATE_LIMIT),
        link_dropout=validation.probability("link_dropout", link_dropout),
        switching=validation.choice("switching", switching, SWITCHING_MODES),
        scenario=scenario,
    )
