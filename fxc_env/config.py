"""Validated environment settings and the observation/action layout they imply.

:func:`make_config` turns the keyword arguments of SPEC 4.1 into an immutable
:class:`EnvConfig`; every bad argument raises an exception that names it. The engine, the
PettingZoo environment, the SB3 VecEnv and the policies all read the same config.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from fxc_env.core.graphs import Topology, make_topology
from fxc_env.core.schedules import Schedule, make_schedule
from fxc_env.scenarios import scenario_kwargs

ACTION_MODES = ("plan", "accel")
SWITCHING_MODES = ("periodic", "random")
OBS_MODES = ("normalized", "raw")
OBS_FORMATS = ("flat", "dict")

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

#: Clock features at the end of every observation: ``t_k / T_s``, ``T_{k+1} / T_s``, ``k / K``.
CLOCK_SIZE = 3


@dataclass(frozen=True, eq=False)
class ObservationLayout:
    """Where things sit in one agent's flat observation vector.

    ``[rows (slots * 2 * dim) | mask (slots) | clock (3)]``; row r is
    ``[x_j - x_i (dim), v_j - v_i (dim)]`` for the r-th in-neighbour j (ascending), zero
    padded. ``slots`` is the largest in-degree over the topology set (``d_max``), or more
    when ``obs_slots`` asks for room (a policy then fits several topologies). In ``normalized`` mode rows are ``(x_j - x_i) / s_i`` and ``T (v_j - v_i) / s_i``.
    """

    slots: int
    dim: int

    @cached_property
    def row_size(self) -> int:
        return 2 * self.dim

    @cached_property
    def rows_end(self) -> int:
        return self.slots * self.row_size

    @cached_property
    def mask_end(self) -> int:
        return self.rows_end + self.slots

    @cached_property
    def size(self) -> int:
        """Length of the flat observation."""
        return self.mask_end + CLOCK_SIZE

    def flat(self, observation: np.ndarray | Mapping[str, Any]) -> np.ndarray:
        """A flat float64 ``(..., size)`` observation from a flat or a dict observation."""
        if isinstance(observation, Mapping):
            neighbours = np.asarray(observation["neighbours"], dtype=np.float64)
            parts = (neighbours.reshape((*neighbours.shape[:-2], -1)), observation["mask"], observation["clock"])
            return np.concatenate([np.asarray(part, dtype=np.float64) for part in parts], axis=-1)
        return np.asarray(observation, dtype=np.float64)

    def split(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(..., size)`` -> rows ``(..., slots, 2, dim)``, mask ``(..., slots)``, clock ``(..., 3)``."""
        lead = obs.shape[:-1]
        rows = obs[..., : self.rows_end].reshape((*lead, self.slots, 2, self.dim))
        return rows, obs[..., self.rows_end : self.mask_end], obs[..., self.mask_end :]


@dataclass(frozen=True, eq=False)
class EnvConfig:
    """Everything that defines an episode family. Build it with :func:`make_config`."""

    topology: Topology
    schedule: Schedule
    dim: int
    obs_slots: int
    action_mode: str
    obs_mode: str
    obs_format: str
    action_bound: float
    reward_floor: float
    initial_state: tuple[np.ndarray, np.ndarray] | None
    position_range: float
    velocity_range: float
    u_max: float | None
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
        return ObservationLayout(self.obs_slots, self.dim)

    @property
    def action_size(self) -> int:
        return 2 * self.dim


RENDER_MODES = ("human", "rgb_array")


def check_render_mode(render_mode: Any) -> None:
    """Raise ``ValueError`` naming ``render_mode`` unless it is None or one of :data:`RENDER_MODES`."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode: expected None or one of {RENDER_MODES}, got {render_mode!r}")


def check_max_cycles(max_cycles: Any) -> None:
    """Raise ``ValueError`` naming ``max_cycles`` unless it is None or an integer >= 1."""
    if max_cycles is not None and (
        isinstance(max_cycles, bool) or not isinstance(max_cycles, int | np.integer) or max_cycles < 1
    ):
        raise ValueError(f"max_cycles: expected None or an integer >= 1, got {max_cycles!r}")


def config_of(source: Any, who: str = "policy") -> EnvConfig:
    """The :class:`EnvConfig` of an environment (parallel, AEC, VecEnv, wrapped) or the config itself."""
    if isinstance(source, EnvConfig):
        return source
    for candidate in (source, getattr(source, "unwrapped", None), getattr(source, "venv", None)):
        config = getattr(candidate, "config", None)
        if isinstance(config, EnvConfig):
            return config
    raise TypeError(
        f"{who}: expected an fxc_env environment (parallel, AEC or VecEnv) or an EnvConfig, got {type(source).__name__}"
    )


def _positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name}: expected an integer >= 1, got {value!r}")
    return int(value)


def _positive_float(name: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: expected a positive finite number, got {value!r}") from exc
    if isinstance(value, bool) or not math.isfinite(number) or number <= 0:
        raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
    return number


def _non_negative_float(name: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: expected a finite number >= 0, got {value!r}") from exc
    if isinstance(value, bool) or not math.isfinite(number) or number < 0:
        raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
    return number


def _choice(name: str, value: Any, options: tuple[str, ...]) -> str:
    if value not in options:
        raise ValueError(f"{name}: expected one of {options}, got {value!r}")
    return value


def validate_state_array(name: str, value: Any, n_agents: int, dim: int) -> np.ndarray:
    """``value`` as a float64 ``(N, dim)`` array (``(N,)`` accepted when ``dim = 1``).

    Raises ``ValueError``/``TypeError`` naming ``name`` for a wrong shape, type or a
    non-finite entry.
    """
    array = np.asarray(value)
    if array.dtype.kind not in "biuf":
        raise TypeError(f"{name}: expected real numbers, got an array of dtype {array.dtype}")
    array = array.astype(np.float64)
    if dim == 1 and array.shape == (n_agents,):
        array = array[:, None]
    if array.shape != (n_agents, dim):
        accepted = f"({n_agents}, {dim})" + (f" or ({n_agents},)" if dim == 1 else "")
        raise ValueError(f"{name}: expected shape {accepted}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: every entry must be finite (no NaN or inf)")
    return array


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
    action_bound: float | None = None,
    reward_floor: float = 1e-12,
    initial_state: Any = None,
    position_range: float = 5.0,
    velocity_range: float = 2.0,
    topology_seed: int | None = 0,
    mean_in_degree: float | None = None,
    topology_period: int | None = None,
    obs_slots: int | None = None,
    u_max: float | None = None,
    obs_noise: float = 0.0,
    link_dropout: float = 0.0,
    switching: str = "periodic",
) -> EnvConfig:
    """Validate SPEC 4.1's keyword arguments (a scenario's values first, explicit ones win).

    A scenario's fixed initial state is dropped (random draws instead) when ``n_agents`` or
    ``dim`` is overridden, since it has the scenario's shape, or when
    ``initial_state="random"``. ``obs_slots`` pads the observation to at least that many
    neighbour rows (default: the topology's largest in-degree).

    Realism options (all off by default): ``u_max`` clips every input component to
    ``[-u_max, u_max]`` m/s^2 (integrated exactly); ``obs_noise`` adds Gaussian noise of
    that standard deviation (m, m/s) to each relative measurement; ``link_dropout`` loses
    each edge at each sampling instant with that probability; ``switching="random"`` draws
    each interval's graph uniformly from the topology set instead of cycling through it.
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
    }
    merged: dict[str, Any] = scenario_kwargs(scenario) if scenario is not None else {}
    scenario_shape = {"n_agents": merged.get("n_agents"), "dim": merged.get("dim", 1)}
    resized = any(given[k] is not None and given[k] != scenario_shape[k] for k in scenario_shape)
    if resized and initial_state is None:
        merged.pop("initial_state", None)  # the scenario's state has the scenario's shape
    merged.update({k: v for k, v in given.items() if v is not None})
    if isinstance(initial_state, str):
        if initial_state != "random":
            raise ValueError(f"initial_state: expected None, 'random' or a pair (x0, v0), got {initial_state!r}")
        merged.pop("initial_state")
    merged.setdefault("topology", "paper_fig1")
    merged.setdefault("settling_time", 20.0)
    merged.setdefault("schedule", "paper")
    merged.setdefault("dim", 1)
    if isinstance(merged["schedule"], str):
        merged.setdefault("n_intervals", 200)

    dim_value = _positive_int("dim", merged["dim"])
    topo = make_topology(
        merged["topology"],
        merged.get("n_agents"),
        seed=topology_seed,
        mean_in_degree=merged.get("mean_in_degree", 2.0),
        period=merged.get("topology_period", 1),
    )
    sched = make_schedule(merged["settling_time"], merged.get("n_intervals"), merged["schedule"])
    slots = topo.max_in_degree
    if obs_slots is not None:
        slots = _positive_int("obs_slots", obs_slots)
        if slots < topo.max_in_degree:
            raise ValueError(
                f"obs_slots: the topology has in-degree up to {topo.max_in_degree}; expected at least that, got {obs_slots!r}"
            )
    action_mode = _choice("action_mode", action_mode, ACTION_MODES)
    obs_mode = _choice("obs_mode", obs_mode, OBS_MODES)
    obs_format = _choice("obs_format", obs_format, OBS_FORMATS)
    bound = (
        DEFAULT_ACTION_BOUNDS[(action_mode, obs_mode)]
        if action_bound is None
        else _positive_float("action_bound", action_bound)
    )
    init = merged.get("initial_state")
    if init is not None:
        if not isinstance(init, tuple | list) or len(init) != 2:
            raise ValueError("initial_state: expected a pair (x0, v0) of arrays of shape (N, dim)")
        init = (
            validate_state_array("initial_state[0] (x0)", init[0], topo.n_agents, dim_value),
            validate_state_array("initial_state[1] (v0)", init[1], topo.n_agents, dim_value),
        )
    if u_max is not None:
        u_max = _positive_float("u_max", u_max)
    noise = _non_negative_float("obs_noise", obs_noise)
    dropout = _non_negative_float("link_dropout", link_dropout)
    if dropout >= 1:
        raise ValueError(f"link_dropout: expected a probability in [0, 1), got {link_dropout!r}")
    switching = _choice("switching", switching, SWITCHING_MODES)
    floor = float(reward_floor)
    if not math.isfinite(floor) or floor <= 0:
        raise ValueError(f"reward_floor: expected a positive finite number, got {reward_floor!r}")
    return EnvConfig(
        topology=topo,
        schedule=sched,
        dim=dim_value,
        obs_slots=slots,
        action_mode=action_mode,
        obs_mode=obs_mode,
        obs_format=obs_format,
        action_bound=bound,
        reward_floor=floor,
        initial_state=init,
        position_range=_positive_float("position_range", position_range),
        velocity_range=_positive_float("velocity_range", velocity_range),
        u_max=u_max,
        obs_noise=noise,
        link_dropout=dropout,
        switching=switching,
        scenario=scenario,
    )
