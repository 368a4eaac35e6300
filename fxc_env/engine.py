"""The batched consensus engine: B independent episodes of N double-integrator agents.

This is the one code path behind every front end: the PettingZoo environment is the
``n_episodes = 1`` case, the SB3 VecEnv and :func:`fxc_env.simulate` use larger batches.
All episodes share a config and advance in lock step (every episode has exactly K
intervals), each with its own initial state. Arrays are float64: positions ``x`` and
velocities ``v`` are ``(B, N, dim)``; observations ``(B, N, obs_size)``; actions
``(B, N, 2 dim)``.

One step integrates the affine input on ``[t_k, t_{k+1})`` in closed form
(:mod:`fxc_env.core.dynamics`), clipped to ``±u_max`` when that is set. Measurement noise,
link dropout and random switching draw from :attr:`ConsensusEngine.rng`, which the front
ends seed; each sampling instant's measurements are drawn once and cached.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core import dynamics, slots, validation
from fxc_env.core.graphs import DENSE_LIMIT, Topology
from fxc_env.core.metrics import SETTLING_THRESHOLDS, EpisodeMetrics, disagreement, reward_floor, spread
from fxc_env.core.validation import ArgumentError

TINY = np.finfo(np.float64).tiny


@dataclass(frozen=True)
class EpisodeDraw:
    """What one episode drew at reset: its initial state ``(N, dim)`` each, and, where the
    config asks for a draw, its topology (a family) and its input limit (a set of ``u_max``)."""

    x0: np.ndarray
    v0: np.ndarray
    topology: Topology | None = None
    u_max: float | None = None


@dataclass(slots=True)
class StepOutcome:
    """What one interval did, per episode ``(B,)`` or per agent ``(B, N)``.

    Attributes:
        reward: team reward ``log(D(t_k) + f) - log(D(t_{k+1}) + f)``, ``(B,)``.
        energy: ``integral |u_i|^2 dt`` over the interval, ``(B, N)``.
        peak_input: peak ``|u_i|`` (largest component) over the interval, ``(B, N)``.
        u_start, u_end: the commanded input at ``t_k+`` and ``t_{k+1}-``, ``(B, N, dim)``
            (the applied input is this line clipped to ``±u_max`` when that is set).
        saturated_fraction: share of the interval spent saturated, mean over components,
            ``(B, N)`` (zeros without ``u_max``).
        terminated: the deadline ``T_s`` was reached (``k = K``).
    """

    reward: np.ndarray
    energy: np.ndarray
    peak_input: np.ndarray
    u_start: np.ndarray
    u_end: np.ndarray
    saturated_fraction: np.ndarray
    terminated: bool


def limit_feature(u_max: np.ndarray | float, interval: float, scale: np.ndarray) -> np.ndarray:
    """How far the input limit binds on the coming interval, scale-free, in ``[-1, 1]``.

    ``rho = u_max T^2 / s_i`` compares the limit with the input a plan at agent i's scale
    needs: the paper's controller starts an interval at about ``6 e / T^2`` (eq. 11), at
    most ``10 s_i / T^2``, so ``rho`` below about 10 means the limit cuts the planned
    input and ``rho >> 10`` that it is out of reach. The feature is ``l / (1 + |l|)`` with
    ``l = log10(rho)``: decades spread evenly (0 at ``rho = 1``, ±0.5 one decade either
    side, ±0.75 three), bounded without a hard clip; ``s_i = 0`` (nothing to correct) gives
    1. Scaling the state and ``u_max`` by the same factor leaves it unchanged. Shape of
    ``scale``, e.g. ``(B, N)``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        decades = np.log10(u_max * interval * interval) - np.log10(scale)
        return np.where(np.isfinite(decades), decades / (1.0 + np.abs(decades)), 1.0)


def _weighted_sum(values: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``xi^T values`` per episode: ``values`` ``(B, N)``, ``xi`` ``(N,)`` or ``(B, N)``."""
    return values @ xi if xi.ndim == 1 else np.einsum("bn,bn->b", values, xi)


def _draw_scale(half_widths: tuple[float, float], rng: np.random.Generator) -> float:
    """``low`` when the range is one number, else a log-uniform draw from ``[low, high]``."""
    low, high = half_widths
    return low if low == high else float(np.exp(rng.uniform(np.log(low), np.log(high))))


class ConsensusEngine:
    """B episodes advanced as arrays. Call :meth:`reset` before :meth:`step`."""

    def __init__(self, config: EnvConfig, n_episodes: int = 1) -> None:
        self.config = config
        self.n_episodes = int(n_episodes)
        self.layout = config.layout
        n, dim = config.n_agents, config.dim
        shape = (self.n_episodes, n, dim)
        #: ``(B, N, 2, dim)``: ``state[:, :, 0]`` positions, ``state[:, :, 1]`` velocities,
        #: side by side so one gather fetches both of a neighbour's values.
        self.state = np.zeros((self.n_episodes, n, 2, dim))
        self._spare = np.zeros_like(self.state)
        self.x0 = np.zeros(shape)
        self.v0 = np.zeros(shape)
        self.k = 0
        #: Each episode's topology (a family draws new ones at every reset, see :meth:`reset`).
        self.topologies: list[Topology] = [config.topology] * self.n_episodes
        self._set_graph_table(self.topologies)
        #: Each episode's input limit ``u_max`` (m/s^2), ``(B,)``, or None without a limit.
        self.u_max: np.ndarray | None = (
            None if config.u_max_choices is None else np.full(self.n_episodes, config.u_max_choices[0])
        )
        schedule = config.schedule
        k_all = np.arange(schedule.n_intervals + 1)
        next_interval = schedule.intervals[np.minimum(k_all, schedule.n_intervals - 1)]
        #: Clock features of every sampling instant: ``t_k / T_s, T_{k+1} / T_s, k / K``, ``(K + 1, 3)``.
        self._clock = np.stack([schedule.times, next_interval, 0 * k_all], axis=1) / schedule.settling_time
        self._clock[:, 2] = k_all / schedule.n_intervals
        self._next_interval = next_interval.tolist()
        #: Per instant, what each flat row entry is multiplied by before the division by s:
        #: 1 for position parts, ``T_{k+1}`` for velocity parts, ``(K + 1, slots * 2 dim)``.
        per_row = np.repeat(np.stack([np.ones_like(next_interval), next_interval], axis=1), config.dim, axis=1)
        self._row_factors = np.tile(per_row, self.layout.slots)
        #: Settling thresholds as a column, ``(len(SETTLING_THRESHOLDS), 1)``.
        self._thresholds = np.array(SETTLING_THRESHOLDS)[:, None]
        #: Generator of measurement noise, link dropout and random switching.
        self.rng = np.random.default_rng()
        self._no_saturation = np.zeros((self.n_episodes, n))
        self._range_weights = np.array([1.0, config.settling_time])
        self._reset_trackers()

    # ------------------------------------------------------------------ state
    @property
    def x(self) -> np.ndarray:
        """Positions ``(B, N, dim)`` at ``t_k`` (a view of :attr:`state`)."""
        return self.state[:, :, 0]

    @property
    def v(self) -> np.ndarray:
        """Velocities ``(B, N, dim)`` at ``t_k`` (a view of :attr:`state`)."""
        return self.state[:, :, 1]

    def sample_initial_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One episode's ``(x0, v0)``: the config's initial state, else uniform draws.

        Positions are drawn from ``U(-a, a)`` and velocities from ``U(-b, b)`` per component,
        with ``a = position_range`` and ``b = velocity_range`` (defaults 5 m and 2 m/s). A
        ``(low, high)`` range first draws the half-width log-uniformly, so episodes span
        decades of scale.
        """
        c = self.config
        if c.initial_state is not None:
            return c.initial_state[0].copy(), c.initial_state[1].copy()
        shape = (c.n_agents, c.dim)
        position_range = _draw_scale(c.position_range, rng)
        velocity_range = _draw_scale(c.velocity_range, rng)
        x0 = rng.uniform(-position_range, position_range, size=shape)
        v0 = rng.uniform(-velocity_range, velocity_range, size=shape)
        return x0, v0

    def draw_episode(self, rng: np.random.Generator) -> EpisodeDraw:
        """What a new episode draws from its seeded generator, in this order.

        Its topology when the config has a family, its input limit when ``u_max`` is a set,
        then ``(x0, v0)`` (:meth:`sample_initial_state`). A config with none of these draws
        exactly what it always did, so seeds keep their episodes.
        """
        c = self.config
        topology = None if c.family is None else c.family.draw(c.n_agents, rng)
        choices = c.u_max_choices
        u_max = None if choices is None else choices[0] if len(choices) == 1 else float(rng.choice(choices))
        x0, v0 = self.sample_initial_state(rng)
        return EpisodeDraw(x0, v0, topology, u_max)

    def reset(
        self,
        x0: np.ndarray,
        v0: np.ndarray,
        rng: np.random.Generator | None = None,
        *,
        topologies: Sequence[Topology | None] | None = None,
        u_max: Sequence[float | None] | np.ndarray | None = None,
    ) -> None:
        """Start every episode at ``t_0 = 0`` from ``x0, v0`` of shape ``(B, N, dim)``.

        ``rng`` (optional) replaces :attr:`rng`, the generator of noise, dropout and random
        switching; without it the current generator goes on. ``topologies`` (one per
        episode; None keeps the config's) and ``u_max`` (one per episode) come from
        :meth:`draw_episode`; without them every episode uses the config's.
        """
        if topologies is not None:
            chosen = [self.config.topology if t is None else t for t in topologies]
            if any(a is not b for a, b in zip(chosen, self.topologies, strict=True)):
                self.topologies = chosen
                self._set_graph_table(chosen)
        if u_max is not None and self.u_max is not None:
            self.u_max = np.array([self.config.u_max_choices[0] if u is None else u for u in u_max], dtype=np.float64)
        self.x[...] = x0
        self.v[...] = v0
        self.x0[...] = x0
        self.v0[...] = v0
        self.k = 0
        if rng is not None:
            self.rng = rng
        self._reset_trackers()

    def validate_state(self, name: str, value: object) -> np.ndarray:
        """A user-given ``(N, dim)`` state array, checked (see :func:`fxc_env.core.validation.state_array`)."""
        return validation.state_array(name, value, self.config.n_agents, self.config.dim)

    def _reset_trackers(self) -> None:
        b, n = self.n_episodes, self.config.n_agents
        self.initial_disagreement = self._disagreement()
        self.current_disagreement = self.initial_disagreement.copy()
        self.floor = reward_floor(self.initial_disagreement, self.config.reward_floor)
        self._log_disagreement = np.log(self.current_disagreement + self.floor)
        d0 = self.initial_disagreement
        self._inverse_d0 = np.divide(1.0, d0, out=np.zeros_like(d0), where=d0 > 0)
        self.energy_total = np.zeros((b, n))
        self.peak_total = np.zeros((b, n))
        # Index of the last sampling instant whose D(t_k)/D(0) was >= eps, per threshold.
        self.last_above = np.zeros((len(SETTLING_THRESHOLDS), b), dtype=np.int64)
        self.saturated_time = np.zeros((b, n))
        self._measured: tuple | None = None
        self._draw_graphs()

    @property
    def done(self) -> bool:
        """The deadline has been reached: ``t_k = T_s``."""
        return self.k >= self.config.schedule.n_intervals

    @property
    def time(self) -> float:
        """Current sampling instant ``t_k`` in seconds."""
        return float(self.config.schedule.times[self.k])

    def current_interval(self) -> float:
        """Length ``T = t_{k+1} - t_k`` of the interval about to be played (seconds)."""
        return self._next_interval[self.k]

    def graph_indices(self) -> np.ndarray:
        """Index, within its own topology, of each episode's graph on the current interval, ``(B,)``."""
        return self._graph_ids - self._graph_offset

    def _set_graph_table(self, topologies: Sequence[Topology]) -> None:
        """Stack every episode's graphs into one table of neighbour slots, padded to the layout's width.

        ``_neighbour_index`` and ``_mask_features`` are ``(G, N, slots)`` over the G distinct
        graphs; episode b uses rows ``_graph_offset[b] + (0 .. m_b - 1)``. Extra slots point
        at the agent itself (a gather then gives exact zeros) and are masked out.
        """
        n, slot_count = self.config.n_agents, self.layout.slots
        unique: dict[int, int] = {}
        index_blocks, mask_blocks, offsets, periods = [], [], [], []
        start = 0
        for topology in topologies:
            if id(topology) not in unique:
                unique[id(topology)] = start
                extra = slot_count - topology.max_in_degree
                own = np.broadcast_to(np.arange(n)[None, :, None], (topology.period, n, extra))
                index_blocks.append(np.concatenate([topology.neighbour_index, own], axis=2))
                mask_blocks.append(
                    np.concatenate([topology.neighbour_mask, np.zeros((topology.period, n, extra), bool)], axis=2)
                )
                start += topology.period
            offsets.append(unique[id(topology)])
            periods.append(topology.period)
        self._neighbour_index = np.concatenate(index_blocks)
        self._mask_features = np.concatenate(mask_blocks).astype(np.float64)
        self._graph_offset = np.array(offsets)
        self._graph_period = np.array(periods)
        #: One topology for all episodes: gathers take the fast path of a single graph.
        self._shared_topology = len(unique) == 1

    def _draw_graphs(self) -> None:
        """Each episode's graph on the coming interval: ``G_{k mod m}``, or a uniform draw (random switching)."""
        periods = self._graph_period
        if self.config.switching == "random":
            if self._shared_topology:
                local = self.rng.integers(0, int(periods[0]), self.n_episodes)
            else:
                local = (self.rng.random(self.n_episodes) * periods).astype(np.int64)
        else:
            local = self.k % periods
        self._graph_ids = self._graph_offset + local
        self._same_graph = self._shared_topology and self.config.switching == "periodic"

    # ------------------------------------------------------------ observation
    def measurements(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the agents measure at ``t_k``, in metres and m/s, drawn once per instant.

        Returns:
            rows ``(B, N, slots, 2, dim)``: ``[x_j - x_i, v_j - v_i]`` per in-neighbour slot
            (padded slots point at i itself and hold exact zeros), with noise and dropout;
            mask ``(B, N, slots)`` or ``(N, slots)`` (1 for a row received); and the local scale
            ``s_i = max(|x_j - x_i|, T |v_j - v_i|)`` over the rows, ``(B, N)``.
        """
        if self._measured is not None and self._measured[0] == self.k:
            return self._measured[1:]
        c = self.config
        if self._same_graph:
            # Gather [x_j, v_j] together (one random access per edge).
            graph = int(self._graph_ids[0])
            rows = np.take(self.state, self._neighbour_index[graph], axis=1, mode="clip")
            mask = self._mask_features[graph]
        else:
            index = self._neighbour_index[self._graph_ids]  # (B, N, slots)
            rows = self.state[np.arange(self.n_episodes)[:, None, None], index]
            mask = self._mask_features[self._graph_ids]
        rows -= self.state[:, :, None]
        if c.link_dropout > 0:
            mask = mask * (self.rng.random((self.n_episodes, *mask.shape[-2:])) >= c.link_dropout)
            rows *= mask[..., None, None]
        if c.obs_noise > 0:
            rows += (c.obs_noise * mask[..., None, None]) * self.rng.standard_normal(rows.shape)
        T = self.current_interval()
        largest = slots.max_abs_rows(rows)  # (B, N, 2): largest |x_j - x_i| and |v_j - v_i|
        scale = np.maximum(largest[..., 0], T * largest[..., 1])
        self._measured = (self.k, rows, mask, scale)
        return rows, mask, scale

    def observations(self, out: np.ndarray | None = None) -> np.ndarray:
        """Every agent's flat observation at ``t_k``, ``(B, N, obs_size)`` (the card's Observation Space).

        ``out`` (optional, ``(B, N, obs_size)`` float64) is filled instead of a fresh
        array: for loops that consume observations at once, it saves the page faults of
        a new large buffer every step. In normalized mode the rows are divided by the local
        scale; division (not multiplication by ``1/s``) keeps every entry within [-1, 1].
        """
        c, layout = self.config, self.layout
        b, n = self.n_episodes, c.n_agents
        raw, mask, scale = self.measurements()
        obs = np.empty((b, n, layout.size)) if out is None else out
        rows = obs[..., : layout.rows_end].reshape(raw.shape)
        if c.obs_mode == "normalized" and layout.slots:
            # s = 0 only when every row is 0; the floor keeps 0 / s at 0 without a branch.
            # Whole rows at once, x parts times 1 and v parts times T, then over s: per entry
            # x / s and (T v) / s as ever, with numpy's inner loops over an agent's whole row
            # rather than over its dim entries (3x faster at dim = 2).
            np.multiply(raw.reshape(b, n, -1), self._row_factors[self.k], out=obs[..., : layout.rows_end])
            obs[..., : layout.rows_end] /= np.maximum(scale, TINY)[:, :, None]
        else:
            rows[...] = raw
        obs[..., layout.rows_end : layout.mask_end] = mask
        obs[..., layout.mask_end : layout.clock_end] = self._clock[self.k]
        if layout.limit_feature:
            obs[..., layout.clock_end] = limit_feature(self.u_max[:, None], self.current_interval(), scale)
        return obs

    def local_scale(self) -> np.ndarray:
        """Each agent's local scale ``s_i`` at ``t_k`` (metres), ``(B, N)``; 0 if it sees no disagreement."""
        return self.measurements()[2]

    # ----------------------------------------------------------------- action
    def validate_actions(self, actions: object, name: str = "actions") -> np.ndarray:
        """A ``(B, N, 2 dim)`` real, finite action array as float64; raise naming ``name`` otherwise."""
        expected = (self.n_episodes, self.config.n_agents, self.config.action_size)
        return validation.action_array(name, actions, expected)

    def inputs_from_actions(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map actions to the affine input's end values ``(u(t_k+), u(t_{k+1}-))`` (the card's Action Space)."""
        c, dim = self.config, self.config.dim
        T = self.current_interval()
        first, second = actions[..., :dim], actions[..., dim:]
        if c.obs_mode == "normalized":
            s = self.local_scale()[..., None]
            if c.action_mode == "plan":
                return dynamics.input_from_plan(s * first, (s / T) * second, T)
            gain = s / (T * T)
            return gain * first, gain * second
        if c.action_mode == "plan":
            return dynamics.input_from_plan(first, second, T)
        return first, second

    def step(self, actions: np.ndarray) -> StepOutcome:
        """Play one interval with already validated ``(B, N, 2 dim)`` actions."""
        if self.done:
            raise RuntimeError("step: the episode reached T_s; reset before stepping again")
        T = self.current_interval()
        u_max = self.u_max
        # Double buffering: the interval is played into the spare buffer, which becomes the
        # state only once the result is known to be finite (a refused step changes nothing).
        previous, following = self.state, self._spare
        with np.errstate(over="ignore", invalid="ignore"):
            u0, u1 = self.inputs_from_actions(actions)
            if u_max is None:
                energy, peak = dynamics.advance_into(self.x, self.v, u0, u1, T, following[:, :, 0], following[:, :, 1])
                saturated_time = None
            else:
                x_next, v_next, energy, peak, saturated_time = dynamics.advance_clipped(
                    self.x, self.v, u0, u1, T, u_max[:, None, None]
                )
                following[:, :, 0] = x_next
                following[:, :, 1] = v_next
            self.state, self._spare = following, previous
            disagreement_next = self._disagreement()
        # One scalar for the finiteness check (a sum overflowing past 1.8e308 is refused too:
        # such energies would overflow the episode's totals).
        if not math.isfinite(disagreement_next.sum() + energy.sum()):
            self.state, self._spare = previous, following
            raise self._overflow_error(actions, energy, disagreement_next)
        if saturated_time is None:
            saturated = self._no_saturation
        else:
            saturated = saturated_time.mean(axis=-1) / T
            self.saturated_time += saturated_time.mean(axis=-1)
        self.k += 1
        self.current_disagreement = disagreement_next
        log_previous = self._log_disagreement
        self._log_disagreement = np.log(self.current_disagreement + self.floor)
        reward = log_previous - self._log_disagreement
        self.energy_total += energy
        np.maximum(self.peak_total, peak, out=self.peak_total)
        above = self.current_disagreement * self._inverse_d0 >= self._thresholds
        np.copyto(self.last_above, self.k, where=above)
        self._draw_graphs()
        return StepOutcome(reward, energy, peak, u0, u1, saturated, self.done)

    def _overflow_error(self, actions: np.ndarray, energy: np.ndarray, disagreement_next: np.ndarray) -> ArgumentError:
        """The error of a step whose result would not be finite in float64, naming what caused it."""
        bad_episodes = np.flatnonzero(~np.isfinite(disagreement_next) | ~np.isfinite(energy).all(axis=-1))
        b = int(bad_episodes[0])
        agents = np.flatnonzero(~np.isfinite(energy[b]) | ~np.isfinite(self._spare[b]).all(axis=(-2, -1)))
        shown = [int(a) for a in agents[:10]]
        episode = f" in episode {b}" if self.n_episodes > 1 else ""
        largest = float(np.max(np.abs(actions[b])))
        return ArgumentError(
            f"actions: the interval k = {self.k} (T = {self.current_interval():g} s) would overflow float64{episode} "
            f"(agents {shown}: a non-finite state, energy or disagreement); the largest action entry is {largest:g}. "
            "The step was refused and the state is unchanged; smaller actions (or a smaller obs_noise / state "
            "scale) keep it finite"
        )

    def _disagreement(self) -> np.ndarray:
        """``D = e_x + T_s e_v`` per episode; for ``dim = 1`` from one max and one min over agents."""
        if self.config.dim == 1:
            values = self.state[..., 0]  # (B, N, 2)
            if values.size > slots.SMALL:
                # Reducing over a middle axis is slow in numpy (10x at N = 1e6); agents last is not.
                values = np.ascontiguousarray(np.swapaxes(values, 1, 2))  # (B, 2, N)
                ranges = values.max(axis=-1) - values.min(axis=-1)
            else:
                ranges = values.max(axis=1) - values.min(axis=1)
            return ranges @ self._range_weights  # e_x + T_s e_v
        return disagreement(self.x, self.v, self.config.settling_time)

    # ---------------------------------------------------------------- metrics
    def batch_metrics(self) -> dict[str, np.ndarray]:
        """The metrics (README, "Baselines and the deadline benchmark") of every episode so far, one ``(B,)`` array per :class:`EpisodeMetrics` field.

        Final values are those at the current instant ``t_k``.
        """
        c = self.config
        times = np.concatenate([c.schedule.times, [np.inf]])
        t_eps = times[self.last_above + 1]  # (thresholds, B)
        # xi (dense, so only for moderate N) is computed on first use, never on the stepping path.
        if c.n_agents <= DENSE_LIMIT and c.switching == "periodic":
            # xi of the shared topology (N,), or of each episode's own (B, N).
            xi = (
                self.topologies[0].consensus_weights()
                if self._shared_topology
                else np.stack([topology.consensus_weights() for topology in self.topologies])
            )
            predicted_v = _weighted_sum(self.v0[:, :, 0], xi)
            predicted_x = _weighted_sum(self.x0[:, :, 0], xi) + c.settling_time * predicted_v
        else:
            predicted_x = predicted_v = np.full(self.n_episodes, np.nan)
        return {
            "final_position_spread": spread(self.x),
            "final_velocity_spread": spread(self.v),
            "relative_deadline_error": self.current_disagreement * self._inverse_d0,
            "t_eps_1e_2": t_eps[0],
            "t_eps_1e_6": t_eps[1],
            "energy": self.energy_total.sum(axis=1),
            "peak_input": self.peak_total.max(axis=1, initial=0.0),
            "sampling_instants": np.full(self.n_episodes, self.k),
            "predicted_final_position": predicted_x,
            "achieved_final_position": self.x[:, :, 0].mean(axis=1),
            "predicted_final_velocity": predicted_v,
            "achieved_final_velocity": self.v[:, :, 0].mean(axis=1),
            "saturated_fraction": self.saturated_time.mean(axis=1) / max(c.schedule.times[self.k], TINY),
        }

    def episode_metrics(self, episode: int = 0) -> EpisodeMetrics:
        """The metrics of one episode so far (see :meth:`batch_metrics`)."""
        return EpisodeMetrics(**{name: column[episode].item() for name, column in self.batch_metrics().items()})
