"""The ParallelEnv's small-N path: one sampling interval of a few agents in Python floats.

At N = 6 (``paper_fig1``) an interval is a few hundred floating-point operations, which the
engine's numpy arrays spend mostly in per-call overhead (dozens of calls on arrays of six
numbers). For few agents, :class:`SmallInterval` plays the same arithmetic in Python floats,
operation for operation in the engine's order, so that every observation, input, state,
energy and peak is bit for bit the engine's (``+ - * /`` round alike in Python and numpy).
The two steps whose rounding numpy may do its own way are left to numpy on arrays of the
engine's shapes: the disagreement's weighted sum ``[e_x, e_v] @ [1, T_s]`` (a fused
multiply-add in BLAS) and the reward's logarithm. Every result is written back into the
:class:`~fxc_env.engine.ConsensusEngine` at once (state, clock, graph, trackers), so the
engine is up to date whenever anyone reads it; the state is read from it at every call, so
code that sets the engine's state directly is followed.

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
from fxc_env.core.metrics import SETTLING_THRESHOLDS

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
        and config.link_dropout == 0
        and config.switching == "periodic"
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
        self.slots = config.layout.slots
        self.size = config.layout.size
        self.normalized = config.obs_mode == "normalized" and self.slots > 0
        self.scaled = config.obs_mode == "normalized"
        self.plan = config.action_mode == "plan"
        self.n_intervals = config.schedule.n_intervals
        self.dtype = np.dtype(config.observation_dtype)
        tables = engine.tables
        #: ``T_{k+1} = t_{k+1} - t_k`` (s), the clock features and the (x, v) row factors, per instant.
        self.next_interval: list[float] = list(tables.next_interval)
        self.features: list[list[float]] = np.asarray(tables.features).tolist()
        self.factors: list[list[float]] = np.asarray(tables.row_factors)[:, :2].tolist()
        #: ``[1, T_s]``: the weights of ``D = e_x + T_s e_v`` (as the engine's agents hold them).
        self.weights = np.array([1.0, config.settling_time])
        self._topology: Any = None
        #: Per graph of the topology, over every (agent, slot) pair, agent major: the agent and its
        #: neighbour in that slot (itself when padded); and the mask, one column per slot.
        self._pairs: list[list[tuple[int, int]]] = []
        self._masks: list[list[list[float]]] = []
        #: ``(instant, the trackers' D(t_k) array, local scales)`` of the last measurement: made once
        #: per instant as the engine does (every reset and step assigns a new ``D(t_k)`` array).
        self._measured: tuple[int, Any, list[float]] = (-1, None, [])

    def _graphs(self, topology: Any) -> None:
        """The neighbour slots of the episode's topology (a family draws a new one at every reset)."""
        if topology is self._topology:
            return
        n, slots, extra = self.n, self.slots, self.slots - topology.max_in_degree
        index, mask = topology.neighbour_index.tolist(), topology.neighbour_mask.tolist()
        self._pairs = [[(i, j) for i, row in enumerate(graph) for j in row + [i] * extra] for graph in index]
        self._masks = [
            [[1.0 if row[s] else 0.0 for row in graph] if s < len(graph[0]) else [0.0] * n for s in range(slots)]
            for graph in mask
        ]
        self._topology = topology
        self._measured = (-1, None, [])

    def _scales(self, k: int, xs: list[float], vs: list[float], dx: list[float], dv: list[float]) -> list[float]:
        """``s_i = max(max_slots |x_j - x_i|, T max_slots |v_j - v_i|)`` per agent (0 without rows)."""
        n, slots = self.n, self.slots
        if slots == 1:
            largest_x, largest_v = list(map(abs, dx)), list(map(abs, dv))
        elif slots:
            ax, av = list(map(abs, dx)), list(map(abs, dv))
            largest_x = [max(ax[a : a + slots]) for a in range(0, n * slots, slots)]
            largest_v = [max(av[a : a + slots]) for a in range(0, n * slots, slots)]
        else:
            largest_x = largest_v = [0.0] * n
        T = self.next_interval[k]
        return [b if b > a else a for a, b in zip(largest_x, [T * b for b in largest_v], strict=True)]

    def observations(self, engine: Any) -> np.ndarray:
        """Every agent's flat observation at ``t_k``, ``(N, obs_size)`` in ``obs_dtype`` (``engine.observations()[0]``)."""
        self._graphs(engine.graphs.topologies[0])
        k, n, slots, size = engine.clock.k, self.n, self.slots, self.size
        flat = engine.state.ravel().tolist()
        xs, vs = flat[0::2], flat[1::2]
        graph = k % len(self._pairs)
        pairs = self._pairs[graph]
        # rows -= state[i]: x_j - x_i and v_j - v_i per (agent, slot).
        dx = [xs[j] - xs[i] for i, j in pairs]
        dv = [vs[j] - vs[i] for i, j in pairs]
        scales = self._scales(k, xs, vs, dx, dv)
        self._measured = (k, engine.trackers.current_disagreement, scales)
        if self.normalized:
            # (x part times 1, v part times T_{k+1}) over max(s_i, tiny), divided as the engine divides.
            f_x, f_v = self.factors[k]
            floors = [s if s > _TINY else _TINY for s in scales]
            dx = [d * f_x / floors[i] for d, (i, _) in zip(dx, pairs, strict=True)]
            dv = [d * f_v / floors[i] for d, (i, _) in zip(dv, pairs, strict=True)]
        values = [0.0] * (n * size)
        masks = self._masks[graph]
        for s in range(slots):
            values[2 * s :: size] = dx[s::slots]
            values[2 * s + 1 :: size] = dv[s::slots]
            values[2 * slots + s :: size] = masks[s]
        for c, entry in enumerate(self.features[k]):
            values[3 * slots + c :: size] = [entry] * n
        return np.array(values, dtype=self.dtype).reshape(n, size)

    def step(self, engine: Any, actions: list[float]) -> tuple[float, list[float], list[float]] | None:
        """Play one interval with the ``2 N`` checked action entries (agent major): ``(reward, energies, peaks)``.

        None, with nothing changed, when the engine is to play it (per-episode clocks, past
        ``T_s``, or a result too large to be sure it is finite: the engine decides and raises).
        """
        clock = engine.clock
        k = clock.k
        if clock.per_episode or k >= self.n_intervals:
            return None
        flat = engine.state.ravel().tolist()
        measured = self._measured
        if (
            measured[0] != k
            or measured[1] is not engine.trackers.current_disagreement
            or engine.graphs.topologies[0] is not self._topology
        ):
            self.observations(engine)
        scales = self._measured[2]
        xs, vs = flat[0::2], flat[1::2]
        T = self.next_interval[k]
        first, second = actions[0::2], actions[1::2]
        # Action -> the affine input's ends (u(t_k+), u(t_{k+1}-)), as the engine's agents and
        # core.dynamics.input_from_plan form them.
        if self.plan:
            inv_t = 1.0 / T
            position_gain, velocity_gain = 6.0 * inv_t * inv_t, 2.0 * inv_t
            if self.scaled:
                position = [position_gain * (s * a) for s, a in zip(scales, first, strict=True)]
                velocity = [velocity_gain * ((s / T) * a) for s, a in zip(scales, second, strict=True)]
            else:
                position = [position_gain * a for a in first]
                velocity = [velocity_gain * a for a in second]
            u0 = [p - q for p, q in zip(position, velocity, strict=True)]
            u1 = [2.0 * q - p for p, q in zip(position, velocity, strict=True)]
        elif self.scaled:
            gains = [s / (T * T) for s in scales]
            u0 = [g * a for g, a in zip(gains, first, strict=True)]
            u1 = [g * a for g, a in zip(gains, second, strict=True)]
        else:
            u0, u1 = first, second
        # The closed forms of core.dynamics.advance_into (paper eq. 10 under an affine input).
        cubic, half, third = T * T / 6.0, 0.5 * T, T / 3.0
        total = [a + b for a, b in zip(u0, u1, strict=True)]
        x_next = [x + (T * v + cubic * (a + t)) for x, v, a, t in zip(xs, vs, u0, total, strict=True)]
        v_next = [v + half * t for v, t in zip(vs, total, strict=True)]
        energies = [(a * t + b * b) * third for a, t, b in zip(u0, total, u1, strict=True)]
        peaks = list(map(max, map(abs, u0), map(abs, u1)))
        if not sum(map(abs, x_next)) + sum(map(abs, v_next)) + sum(energies) <= _LARGE:  # false for nan too
            return None
        # D = e_x + T_s e_v at dim = 1: the ranges (exact in any order), weighted by numpy.
        disagreement = np.array([[max(x_next) - min(x_next), max(v_next) - min(v_next)]]) @ self.weights
        if not float(disagreement[0]) <= _LARGE:
            return None
        following = [0.0] * (2 * self.n)
        following[0::2], following[1::2] = x_next, v_next
        engine.state.flat[:] = following
        # The trackers, clock, measurements and graph, as ConsensusEngine.step leaves them.
        trackers = engine.trackers
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
        for row, threshold in enumerate(SETTLING_THRESHOLDS):
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
