"""The ParallelEnv's small-N path: one sampling interval of a few agents in Python floats.

For few agents, :class:`SmallInterval` plays the engine's interval maps
(:func:`fxc_env.core.dynamics.input_ends`, :func:`~fxc_env.core.dynamics.interval_increments`)
on Python floats, bit for bit the engine's, and writes every result back into the
:class:`~fxc_env.engine.ConsensusEngine` at once (docs: performance.md, "The small-N path").

It covers the double integrator's closed forms (paper eqs. 10-11) at ``dim = 1`` with
periodic switching in lock step, without input limit, observation noise or link dropout,
in either action and observation mode (:func:`applies`). An interval whose result could
overflow goes through :meth:`ConsensusEngine.step`, which refuses it with its own error
and leaves the state unchanged.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.dynamics import input_ends, interval_increments
from fxc_env.core.metrics import TRACKED_THRESHOLDS

#: Largest N the small path takes (beyond, the engine's vectorised step is as fast).
SMALL_N = 16
#: A sum of state entries and energies, or a disagreement, above this sends the interval to the
#: engine, which decides on overflow with its own sums (below, every sum of them is finite).
_LARGE = 1e300
_TINY = float(np.finfo(np.float64).tiny)
#: The engine's parts the small path reads and writes (see :mod:`fxc_env.engine.consensus_engine`).
_PARTS = {
    "clock": ("k", "advance", "per_episode"),
    "tables": ("next_interval", "features", "row_factors"),
    "graphs": ("topologies", "draw"),
    "observer": ("invalidate",),
    "backend": ("quiet_disagreement",),
    "trackers": (
        "current_disagreement",
        "log_disagreement",
        "floor",
        "inverse_d0",
        "energy_total",
        "peak_total",
        "last_above",
    ),
}


def applies(config: EnvConfig, engine: Any) -> bool:
    """Whether :class:`SmallInterval` covers this environment's episodes (see the module docstring)."""
    covered = (
        config.n_agents <= SMALL_N
        and config.dim == 1
        and config.model is None
        and config.u_max_choices is None
        and config.obs_noise == 0
        and config.obs_resolution == 0
        and config.link_dropout == 0
        and config.switching == "periodic"
        and config.action_mode != "residual"
        and not config.layout.limit_feature
        and getattr(engine, "is_numpy", False)
        and getattr(engine, "n_episodes", 0) == 1
        and hasattr(engine, "_switching_draw")
    )
    return covered and all(
        all(hasattr(getattr(engine, part, None), name) for name in names) for part, names in _PARTS.items()
    )


class SmallInterval:
    """Observations and intervals of the engine's one episode of few agents (``dim = 1``).

    Args:
        config: the environment's settings (:func:`applies` is true for them).
        engine: the environment's engine, whose tables (interval lengths, clock features, row
            factors) are read once.
    """

    def __init__(self, config: EnvConfig, engine: Any) -> None:
        self.n = config.n_agents
        self.action_size = config.action_size
        self.slots = config.layout.slots
        self.size = config.layout.size
        self.normalized = config.obs_mode == "normalized" and self.slots > 0
        #: The action's input ends (:func:`fxc_env.core.dynamics.input_ends`), chosen as the engine's agents choose it.
        self.ends = input_ends(
            config.action_mode in ("plan", "plan_balanced"), config.obs_mode == "normalized", config.velocity_weight
        )
        #: What velocities are weighed by in the local scale: ``T_s`` (``plan_balanced``), else None (``T_{k+1}``).
        self.velocity_weight = config.velocity_weight
        self.n_intervals = config.schedule.n_intervals
        self.dtype = np.dtype(config.observation_dtype)
        tables = engine.tables
        #: ``T_{k+1} = t_{k+1} - t_k`` (s), the clock features and the (x, v) row factors, per instant.
        self.next_interval: list[float] = list(tables.next_interval)
        self.features: list[list[float]] = np.asarray(tables.features).tolist()
        self.factors: list[list[float]] = np.asarray(tables.row_factors)[:, :2].tolist()
        #: ``[1, T_s]``: the weights of ``D = e_x + T_s e_v`` (as the engine's agents hold them).
        self.weights = np.array([1.0, config.settling_time])
        #: A disagreement above this goes to the engine: 1e300, or with raw float32 observations
        #: the engine's bound below which no two states can differ beyond float32's range.
        self.large = min(_LARGE, engine.backend.quiet_disagreement)
        self._topology: Any = None
        #: Per graph of the topology, per agent: the neighbour in each slot (itself when padded) and the mask.
        self._neighbours: list[list[list[int]]] = []
        self._masks: list[list[list[float]]] = []
        #: ``(instant, the trackers' D(t_k) array, local scales)`` of the last measurement: made once
        #: per instant as the engine does (every reset and step assigns a new ``D(t_k)`` array).
        self._measured: tuple[int, Any, list[float]] = (-1, None, [])

    def _graphs(self, topology: Any) -> None:
        """The neighbour slots of the episode's topology (a family draws a new one at every reset)."""
        if topology is self._topology:
            return
        extra = self.slots - topology.max_in_degree
        index, mask = topology.neighbour_index.tolist(), topology.neighbour_mask.tolist()
        self._neighbours = [[row + [i] * extra for i, row in enumerate(graph)] for graph in index]
        self._masks = [[[1.0 if m else 0.0 for m in row] + [0.0] * extra for row in graph] for graph in mask]
        self._topology = topology
        self._measured = (-1, None, [])

    def observations(self, engine: Any) -> np.ndarray:
        """Every agent's flat observation at ``t_k``, ``(N, obs_size)`` in ``obs_dtype`` (``engine.observations()[0]``)."""
        self._graphs(engine.graphs.topologies[0])
        k = engine.clock.k
        flat = engine.state.ravel().tolist()
        xs, vs = flat[0::2], flat[1::2]
        graph = k % len(self._neighbours)
        T = self.next_interval[k] if self.velocity_weight is None else self.velocity_weight
        f_x, f_v = self.factors[k]
        features = self.features[k]
        normalized = self.normalized
        values: list[float] = []
        scales: list[float] = []
        if self.slots == 1 and normalized:
            # One in-neighbour slot (paper_fig1, rings, paths): the loop below without its inner loops.
            for (j,), mask, x_i, v_i in zip(self._neighbours[graph], self._masks[graph], xs, vs, strict=True):
                dx, dv = xs[j] - x_i, vs[j] - v_i
                largest_x = abs(dx)
                scale = T * abs(dv)
                if not scale > largest_x:
                    scale = largest_x
                scales.append(scale)
                floor = scale if scale > _TINY else _TINY
                values += (dx * f_x / floor, dv * f_v / floor)
                values += mask
                values += features
            self._measured = (k, engine.trackers.current_disagreement, scales)
            return np.array(values, dtype=self.dtype).reshape(self.n, self.size)
        for neighbours, mask, x_i, v_i in zip(self._neighbours[graph], self._masks[graph], xs, vs, strict=True):
            # rows -= state[i]: x_j - x_i and v_j - v_i per slot (padded slots: i itself, exact zeros);
            # s_i = max(max_slots |x_j - x_i|, T max_slots |v_j - v_i|), 0 without rows (T_s: plan_balanced).
            rows: list[float] = []
            largest_x = largest_v = 0.0
            for j in neighbours:
                dx, dv = xs[j] - x_i, vs[j] - v_i
                rows += (dx, dv)
                if abs(dx) > largest_x:
                    largest_x = abs(dx)
                if abs(dv) > largest_v:
                    largest_v = abs(dv)
            scale = T * largest_v
            if not scale > largest_x:
                scale = largest_x
            scales.append(scale)
            if normalized:
                # (x part times 1, v part times T_{k+1} or T_s) over max(s_i, tiny), divided as the engine divides.
                floor = scale if scale > _TINY else _TINY
                for position in range(0, len(rows), 2):
                    values += (rows[position] * f_x / floor, rows[position + 1] * f_v / floor)
            else:
                values += rows
            values += mask
            values += features
        self._measured = (k, engine.trackers.current_disagreement, scales)
        return np.array(values, dtype=self.dtype).reshape(self.n, self.size)

    def step(self, engine: Any, actions: list[float]) -> tuple[float, list[float], list[float]] | None:
        """Play one interval with the ``2 N`` checked action entries (agent major): ``(reward, energies, peaks)``.

        None, with nothing changed, when the engine is to play it (per-episode clocks, past
        ``T_s``, or a result too large to be sure it is finite: the engine decides and raises).
        """
        clock = engine.clock
        k = clock.k
        if clock.per_episode or k >= self.n_intervals:
            return None
        trackers = engine.trackers
        measured = self._measured
        if (
            measured[0] != k
            or measured[1] is not trackers.current_disagreement
            or engine.graphs.topologies[0] is not self._topology
        ):
            self.observations(engine)
        flat = engine.state.ravel().tolist()
        T = self.next_interval[k]
        ends, increments = self.ends, interval_increments
        following: list[float] = []
        energies: list[float] = []
        peaks: list[float] = []
        for s, first, second, x, v in zip(
            self._measured[2], actions[0::2], actions[1::2], flat[0::2], flat[1::2], strict=True
        ):
            # The engine's very maps (core.dynamics), on floats: the input's ends, then paper eq. 10.
            u0, u1 = ends(first, second, T, s)
            dx, dv, energy = increments(v, u0, u1, T)
            following += (x + dx, v + dv)
            energies.append(energy)
            peaks.append(max(abs(u0), abs(u1)))
        if not sum(map(abs, following)) + sum(energies) <= _LARGE:  # false for nan too
            return None
        # D = e_x + T_s e_v at dim = 1: the ranges (exact in any order), weighted by numpy.
        x_next, v_next = following[0::2], following[1::2]
        disagreement = np.array([[max(x_next) - min(x_next), max(v_next) - min(v_next)]]) @ self.weights
        if not float(disagreement[0]) <= self.large:
            return None
        engine.state.flat[:] = following
        # The trackers, clock, measurements and graph, as ConsensusEngine.step leaves them.
        trackers.current_disagreement = disagreement
        previous = trackers.log_disagreement
        trackers.log_disagreement = np.log(disagreement + trackers.floor)
        reward = float(previous[0]) - float(trackers.log_disagreement[0])
        totals = trackers.energy_total
        totals.flat[:] = [a + b for a, b in zip(totals.ravel().tolist(), energies, strict=True)]
        highest = trackers.peak_total
        highest.flat[:] = list(map(max, highest.ravel().tolist(), peaks))
        reached = clock.advance()
        relative = float(disagreement[0]) * float(trackers.inverse_d0[0])
        for row, threshold in enumerate(TRACKED_THRESHOLDS):
            if relative >= threshold:
                trackers.last_above[row, 0] = reached
        engine.observer.invalidate()
        engine.graphs.draw(clock, engine._switching_draw)
        return reward, energies, peaks


def checked_values(actions: Any, agents: list[str], size: int) -> list[float] | None:
    """The entries of ``actions`` (a dict over exactly ``agents``) as floats, agent major.

    Only the common case: float32 or float64 arrays of shape ``(size,)`` with finite entries.
    None otherwise (the caller's full check then names what is wrong, or converts other
    array-likes).
    """
    if type(actions) is not dict or len(actions) != len(agents):
        return None
    values: list[float] = []
    shape = (size,)
    for agent in agents:
        action = actions.get(agent)
        if type(action) is not np.ndarray or action.shape != shape or action.dtype.char not in "df":
            return None
        values += action.tolist()
    return values if all(map(math.isfinite, values)) else None
