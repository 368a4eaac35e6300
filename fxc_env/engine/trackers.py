"""The episode trackers: rewards and the running figures behind the episode metrics.

Per episode, from its last reset: the initial state (kept whole, for metrics that need it),
the disagreement ``D(t_k) = e_x + T_s e_v`` (paper eq. 7's figure of merit) at the start
and now, the reward's floor and logarithm, the energy and peak input per agent, the last
instant above each settling threshold, and the time spent saturated. :meth:`EpisodeTrackers.update`
folds one :class:`~fxc_env.engine.agents.Interval` in; :meth:`EpisodeTrackers.batch_metrics`
turns them into the metrics (docs: benchmark.md, "Baselines and the deadline benchmark"), the
predicted consensus value by :func:`fxc_env.core.linear.final_value` (Theorems 1-2).

To add a metric: extend :meth:`EpisodeTrackers.extra_metrics`; its columns join
:meth:`~EpisodeTrackers.batch_metrics`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.floors import input_floor, noise_floor, resolution_floor
from fxc_env.core.graphs import DENSE_LIMIT
from fxc_env.core.linear import LinearModel, final_value, model_matrices
from fxc_env.core.metrics import TRACKED_THRESHOLDS, reward_floor, spread, spread_any
from fxc_env.core.optimality import episode_energy_bound, reach_intervals

from .backend import TINY, to_host


class EpisodeTrackers:
    """Running figures of B episodes, reset per episode (partial resets included).

    Args:
        config: the environment's settings.
        backend: the engine's array backend.

    Attributes:
        x0, v0: each episode's initial positions and velocities, ``(B, N, dim)``.
        z0: each episode's initial state in the engine's coordinates ``(B, N, n, dim)``
            (the formation error with formation offsets).
        initial_disagreement, current_disagreement: ``D(0)`` and ``D(t_k)``, ``(B,)``.
        energy_total, peak_total: ``integral |u_i|^2`` so far and the peak ``|u_i|``, ``(B, N)``.
        last_above: per settling threshold, the last instant with ``D(t_k) / D(0) >= eps``,
            ``(len(TRACKED_THRESHOLDS), B)``.
        saturated_time: seconds saturated per agent (mean over components), ``(B, N)``.
    """

    def __init__(self, config: EnvConfig, backend: Any) -> None:
        self.config = config
        self.backend = backend
        b, n, n_states, dim = backend.n_episodes, config.n_agents, config.n_states, config.dim
        self.x0 = backend.zeros((b, n, dim))
        self.v0 = backend.zeros((b, n, dim))
        self.z0 = backend.zeros((b, n, n_states, dim))
        #: Settling thresholds as a column, ``(len(TRACKED_THRESHOLDS), 1)``.
        self._thresholds = backend.array(np.array(TRACKED_THRESHOLDS)[:, None])
        self._model = config.model if config.model is not None else LinearModel(*model_matrices("double_integrator"))
        #: ``(topology, (radius_bound, all_roots_bound))`` by the topology's id (a graph's bounds are computed once).
        self._bounds_cache: dict[int, tuple[Any, tuple[float, float]]] = {}
        #: ``(topology, noise floor at sigma = 1 in metres)`` by the topology's id, likewise.
        self._noise: dict[tuple[str, int], tuple[Any, float]] = {}
        #: The initial states (host) the input floors were computed for, and the floors (m/s^2), ``(B,)``.
        self._input_floor: tuple[np.ndarray, np.ndarray] | None = None

    def restart(self, x0: Any, v0: Any, fresh: Any, disagreement: Any, episodes: Any = None) -> None:
        """Start the trackers of ``episodes`` (a ``(B,)`` mask; None: all) from ``x0, v0`` and state ``fresh``.

        ``disagreement`` is ``D(0)`` of ``fresh`` per episode, ``(B,)``.
        """
        xp, backend = self.backend.xp, self.backend
        b, n = backend.n_episodes, self.config.n_agents
        floor = reward_floor(disagreement, self.config.reward_floor)
        inverse_d0 = 1.0 / xp.where(disagreement > 0, disagreement, xp.ones_like(disagreement))
        inverse_d0 = xp.where(disagreement > 0, inverse_d0, xp.zeros_like(disagreement))
        log_disagreement = xp.log(disagreement + floor)
        last_above = xp.zeros((len(TRACKED_THRESHOLDS), b), dtype=xp.int64, device=backend.device)
        if episodes is None:
            if backend.is_numpy:
                self.z0[...] = fresh
                self.x0[...] = x0
                self.v0[...] = v0
            else:  # new tensors, not writes into the old ones: the previous episodes' graph is let go
                self.z0, self.x0, self.v0 = fresh, x0, v0
            self.initial_disagreement = disagreement
            self.current_disagreement = xp.asarray(disagreement, copy=True)
            self.floor = floor
            self.log_disagreement = log_disagreement
            self.inverse_d0 = inverse_d0
            self.energy_total = backend.zeros((b, n))
            self.peak_total = backend.zeros((b, n))
            self.last_above = last_above
            self.saturated_time = backend.zeros((b, n))
            return
        keep = xp.reshape(episodes, (-1, 1, 1))
        self.x0 = xp.where(keep, x0, self.x0)
        self.v0 = xp.where(keep, v0, self.v0)
        self.z0 = xp.where(xp.reshape(episodes, (-1, 1, 1, 1)), fresh, self.z0)
        per_agent = xp.reshape(episodes, (-1, 1))
        self.initial_disagreement = xp.where(episodes, disagreement, self.initial_disagreement)
        self.current_disagreement = xp.where(episodes, disagreement, self.current_disagreement)
        self.floor = xp.where(episodes, floor, self.floor)
        self.log_disagreement = xp.where(episodes, log_disagreement, self.log_disagreement)
        self.inverse_d0 = xp.where(episodes, inverse_d0, self.inverse_d0)
        self.energy_total = xp.where(per_agent, xp.zeros_like(self.energy_total), self.energy_total)
        self.peak_total = xp.where(per_agent, xp.zeros_like(self.peak_total), self.peak_total)
        self.last_above = xp.where(episodes, last_above, self.last_above)
        self.saturated_time = xp.where(per_agent, xp.zeros_like(self.saturated_time), self.saturated_time)

    def update(self, interval: Any, reached: Any) -> Any:
        """Fold one interval in; ``reached`` is the instant now reached (an int, or ``(B,)``). Returns the reward ``(B,)``.

        The reward is ``log(D(t_k) + f) - log(D(t_{k+1}) + f)`` with the floor ``f``.
        """
        xp = self.backend.xp
        if interval.saturated_time is not None:
            self.saturated_time = self._accumulate(self.saturated_time, interval.saturated_time)
        self.current_disagreement = interval.disagreement
        log_previous = self.log_disagreement
        self.log_disagreement = xp.log(self.current_disagreement + self.floor)
        self.energy_total = self._accumulate(self.energy_total, interval.energy)
        self.peak_total = xp.maximum(self.peak_total, interval.peak)
        above = self.current_disagreement * self.inverse_d0 >= self._thresholds
        if self.backend.is_numpy and isinstance(reached, int):
            np.copyto(self.last_above, reached, where=above)  # numpy fast path: in place, lock step
        else:
            self.last_above = xp.where(above, reached + xp.zeros_like(self.last_above), self.last_above)
        return log_previous - self.log_disagreement

    def _accumulate(self, total: Any, value: Any) -> Any:
        """``total + value``: in place on numpy, a new tensor on torch (no in-place write on the autograd path)."""
        if self.backend.is_numpy:
            total += value
            return total
        return total + value

    def batch_metrics(self, state: Any, steps: np.ndarray, topologies: list, shared: bool) -> dict[str, np.ndarray]:
        """The metrics of every episode so far, one ``(B,)`` numpy array per :class:`~fxc_env.core.metrics.EpisodeMetrics` field.

        ``state`` ``(B, N, n, dim)`` is the engine's now, ``steps`` ``(B,)`` each episode's instant
        (host), ``topologies`` one per episode (``shared``: all the same object). On torch this
        reads off the device.
        """
        c = self.config
        state = to_host(state)
        x = state[:, :, 0]
        v = state[:, :, 1] if c.n_states > 1 else np.zeros_like(x)
        times = np.concatenate([c.schedule.times, [np.inf]])
        t_eps = times[to_host(self.last_above) + 1]  # (thresholds, B)
        predicted = self.predicted_final_state(topologies, shared)  # (B, 2)
        elapsed = np.maximum(c.schedule.times[steps], TINY)
        metrics = {
            "final_position_spread": spread(x),
            "final_velocity_spread": spread(v),
            "relative_deadline_error": to_host(self.current_disagreement * self.inverse_d0),
            "t_eps_1e_2": t_eps[0],
            "t_eps_1e_6": t_eps[1],
            "energy": to_host(self.energy_total).sum(axis=1),
            "peak_input": to_host(self.peak_total).max(axis=1, initial=0.0),
            "sampling_instants": steps.astype(np.int64),
            "predicted_final_position": predicted[:, 0],
            "achieved_final_position": x[:, :, 0].mean(axis=1),
            "predicted_final_velocity": predicted[:, 1],
            "achieved_final_velocity": v[:, :, 0].mean(axis=1),
            "saturated_fraction": to_host(self.saturated_time).mean(axis=1) / elapsed,
        }
        metrics.update(self.optimality_metrics(metrics["energy"], topologies))
        metrics.update(self.extra_metrics(state, steps))
        return metrics

    def metric_tensors(self, state: Any, steps: Any) -> dict[str, Any]:
        """The metrics of :meth:`batch_metrics` that are functions of the actions, as ``(B,)`` arrays of the backend.

        ``final_position_spread``, ``final_velocity_spread``, ``relative_deadline_error``,
        ``energy``, ``peak_input``, ``achieved_final_position``, ``achieved_final_velocity`` and
        ``saturated_fraction``, from ``state`` (the engine's now) and ``steps`` (each episode's
        instant, ``(B,)`` on the device): on torch they stay on the device, in the autograd
        graph of the actions (no read off the device). The other columns are counts, instants
        or figures of the initial state and graph.
        """
        xp, backend, c = self.backend.xp, self.backend, self.config
        x = state[:, :, 0]
        v = state[:, :, 1] if c.n_states > 1 else xp.zeros_like(x)
        elapsed = xp.take(backend.array(c.schedule.times), steps, axis=0)
        return {
            "final_position_spread": spread_any(x),
            "final_velocity_spread": spread_any(v),
            "relative_deadline_error": self.current_disagreement * self.inverse_d0,
            "energy": xp.sum(self.energy_total, axis=1),
            "peak_input": xp.max(self.peak_total, axis=1),
            "achieved_final_position": xp.mean(x[:, :, 0], axis=1),
            "achieved_final_velocity": xp.mean(v[:, :, 0], axis=1),
            "saturated_fraction": xp.mean(self.saturated_time, axis=1) / xp.maximum(elapsed, backend.full((), TINY)),
        }

    def detach(self) -> None:
        """torch: the running figures as new tensors with no autograd history (:meth:`ConsensusEngine.cut_graph`)."""
        for name in self._RUNNING:
            setattr(self, name, getattr(self, name).detach())

    #: The per-episode tensors :meth:`restart` and :meth:`update` keep (those :meth:`detach` cuts).
    _RUNNING = (
        "x0",
        "v0",
        "z0",
        "initial_disagreement",
        "current_disagreement",
        "floor",
        "log_disagreement",
        "inverse_d0",
        "energy_total",
        "peak_total",
        "saturated_time",
    )

    def optimality_metrics(self, energy: np.ndarray, topologies: list) -> dict[str, np.ndarray]:
        """``energy_bound`` (E*), ``energy_ratio``, ``settled_interval``, ``radius_bound`` and ``all_roots_bound``.

        Each ``(B,)``. E* from each episode's initial state
        (:func:`fxc_env.core.optimality.episode_energy_bound`); the settled interval from the trackers'
        last instant at or above the tolerance; the intervals bounds of each episode's own graph
        (:func:`fxc_env.core.optimality.radius_bound`, every law; :func:`~fxc_env.core.optimality.all_roots_bound`,
        laws whose value depends on every root; cached per topology; NaN for random switching and
        above ``DENSE_LIMIT`` agents). ``propagation_bound``, deprecated, repeats ``all_roots_bound``.
        """
        c = self.config
        bound = episode_energy_bound(c.model, to_host(self.z0), c.settling_time)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(bound > 0, energy / np.where(bound > 0, bound, 1.0), np.nan)
        below = to_host(self.current_disagreement * self.inverse_d0) < TRACKED_THRESHOLDS[-1]
        settled = np.where(below, to_host(self.last_above[-1]) + 1.0, np.inf)
        metrics = {
            "energy_bound": bound,
            "energy_ratio": ratio,
            "settled_interval": settled,
            "noise_floor": self._noise_floor(topologies),
            "resolution_floor": self._resolution_floor(topologies),
            "input_floor": self._input_floors(),
        }
        bounds = np.array([self._intervals_bounds(topology) for topology in topologies]).reshape(-1, 2)
        metrics.update(radius_bound=bounds[:, 0], all_roots_bound=bounds[:, 1], propagation_bound=bounds[:, 1].copy())
        return metrics

    def _noise_floor(self, topologies: list) -> np.ndarray:
        """``noise_floor``: the least expected ``D(T_s) / D(0)`` under ``obs_noise`` (:func:`fxc_env.core.floors.noise_floor`).

        NaN without noise, for other agent models, with random switching and above
        :data:`fxc_env.core.floors.NOISE_LIMIT` agents; cached per topology (at sigma = 1).
        """
        c = self.config
        if c.obs_noise == 0 or c.model is not None or c.switching != "periodic":
            return np.full(len(topologies), np.nan)
        floors = [self._per_topology("noise", topology, noise_floor) for topology in topologies]
        with np.errstate(invalid="ignore"):
            return c.obs_noise * np.array(floors) * to_host(self.inverse_d0)

    def _resolution_floor(self, topologies: list) -> np.ndarray:
        """``resolution_floor``: the worst ``D(T_s)`` over the states that read all zeros at ``obs_resolution``, over ``D(0)``.

        :func:`fxc_env.core.floors.resolution_floor` (metres) over each episode's ``D(0)``: a
        worst case over a set of initial states (docs: optimality.md, "The floors, derived"), not a
        bound on each episode. NaN without a quantum, under ``obs_noise``, for other agent models
        and with random switching; cached per topology (at quantum 1).
        """
        c = self.config
        if c.obs_resolution == 0 or c.obs_noise != 0 or c.model is not None or c.switching != "periodic":
            return np.full(len(topologies), np.nan)
        floors = [self._per_topology("resolution", topology, resolution_floor) for topology in topologies]
        with np.errstate(invalid="ignore", divide="ignore"):
            return c.obs_resolution * np.array(floors) * to_host(self.inverse_d0)

    def _per_topology(self, kind: str, topology: Any, floor: Any) -> float:
        """``floor(topology, times, 1.0, dim)`` cached per topology object (64 at most)."""
        cached = self._noise.get((kind, id(topology)))
        if cached is None or cached[0] is not topology:
            if len(self._noise) >= 64:
                self._noise.clear()
            value = float(floor(topology, self.config.schedule.times, 1.0, self.config.dim))
            cached = self._noise[(kind, id(topology))] = (topology, value)
        return cached[1]

    def _input_floors(self) -> np.ndarray:
        """``input_floor``: the least ``u_max`` (m/s^2) of exact consensus (:func:`fxc_env.core.floors.input_floor`).

        A linear programme per episode (40-190 ms of CPU at N = 20 to 1000), solved once per
        initial state on first use; NaN without an input limit and for other agent models.
        """
        c = self.config
        if c.u_max_choices is None or c.model is not None:
            return np.full(self.backend.n_episodes, np.nan)
        z0 = np.array(to_host(self.z0), dtype=np.float64)
        if self._input_floor is None:
            known, floors = np.full_like(z0, np.nan), np.full(len(z0), np.nan)
        else:
            known, floors = self._input_floor
        for b in np.flatnonzero(np.any(z0 != known, axis=(1, 2, 3))):
            floors[b] = input_floor(z0[b, :, 0], z0[b, :, 1], c.settling_time)
        self._input_floor = (z0, floors)
        return floors.copy()

    def _intervals_bounds(self, topology: Any) -> tuple[float, float]:
        if self.config.switching != "periodic" or topology.n_agents > DENSE_LIMIT:
            return np.nan, np.nan
        cached = self._bounds_cache.get(id(topology))
        if cached is None or cached[0] is not topology:  # an id is only unique while its object lives
            if len(self._bounds_cache) >= 64:  # families draw a graph per episode: keep the cache small
                self._bounds_cache.clear()
            intervals = reach_intervals(topology)[1]
            cached = self._bounds_cache[id(topology)] = (topology, (float(intervals.min()), float(intervals.max())))
        return cached[1]

    def predicted_final_state(self, topologies: list, shared: bool) -> np.ndarray:
        """Position and velocity of ``z*(T_s)`` on the first space axis per episode, ``(B, 2)`` (NaN where not known).

        Theorems 1-2 (generalised, :func:`fxc_env.core.linear.final_value`): ``z*(T_s) =
        e^{A T_s} sum_j xi_j z_j(0)`` in the engine's coordinates, with the consensus weights
        ``xi`` of each episode's periodic topology (dense, so only for N up to ``DENSE_LIMIT``;
        computed on first use, never on the stepping path). Random switching has no such value.
        A single integrator's velocity is 0.
        """
        c = self.config
        if c.n_agents > DENSE_LIMIT or c.switching != "periodic":
            return np.full((self.backend.n_episodes, 2), np.nan)
        if shared:
            xi = topologies[0].consensus_weights()  # (N,)
        else:
            xi = np.stack([topology.consensus_weights() for topology in topologies])  # (B, N)
        z0 = np.swapaxes(to_host(self.z0)[:, :, :, :1], -1, -2)  # (B, N, 1, n): the first axis, core.linear's order
        final = final_value(self._model, xi, z0, c.settling_time)[:, 0, :]  # (B, n)
        return final[:, :2] if c.n_states > 1 else np.concatenate([final, np.zeros_like(final)], axis=1)

    def extra_metrics(self, state: np.ndarray, steps: np.ndarray) -> dict[str, np.ndarray]:
        """Further ``(B,)`` metric columns for :meth:`batch_metrics` (none here): the place to add metrics.

        ``state`` is the engine's state now (host, ``(B, N, n, dim)``), ``steps`` each
        episode's instant; :attr:`z0`, :attr:`initial_disagreement` and the running totals
        are on ``self``.
        """
        return {}
