"""Exact consensus under an input limit: gather every prediction by small motions, then the least-peak steer.

Law, source, proven graph class and refusals: docs: optimality.md, "Under an input limit (`bounded_steer`)".
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from scipy.sparse import csgraph

from fxc_env.baselines.laws.motion_signals import (
    SignalPolicy,
    advance,
    deviation_of,
    initial_offset,
    predicted_register,
    read_deviation,
    refuse_unless_exact_raw_rows,
    register_of,
    signal_amplitude,
    signal_plan,
)
from fxc_env.baselines.laws.policy import lost_link_guarantee, rows_read
from fxc_env.config import config_of, make_config
from fxc_env.core.floors import input_floor
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine, EpisodeDraw

__all__ = ["BoundedSteerPolicy", "errors_at_limit_ratios", "flooding_schedule", "least_peak_inputs"]

#: Default signalling amplitude ε (the signalling law's): reads off by about 1e-16 |z| / ε.
DEFAULT_AMPLITUDE = 1e-6

#: The ratios ``u_max / input_floor`` of the law's measured table (docs: optimality.md, "Under an input limit").
LIMIT_RATIOS = (1.01, 1.1, 1.25, 1.3, 1.35, 1.5, 2.0)
#: The ratio ``u_max / input_floor`` the law needs, as measured by :func:`errors_at_limit_ratios` (ring of 20).
LIMIT_MARGIN = (
    "on a directed ring of 20 (K = 200 uniform, 20 seeds, each at its own input floor) no seed is exact at u_max = "
    "1.01, 1.1 or 1.25 x the floor (median D(T_s)/D(0) 0.35, 0.22, 0.0077), 19 of 20 at 1.3 and every seed from "
    "1.35 on: the steer starts after the gathering (1.8 s there), and (20 / 18.2)² = 1.21 of the margin is that "
    "shorter horizon alone, the rest the mid-range point in place of the best common one"
)


def flooding_schedule(index: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``(S, N)``: the agent whose relative prediction each agent sends at instants ``0 .. S - 1`` (-1: none).

    ``index``/``mask`` ``(N, d_max)``: each agent's in-neighbours per row slot. Agent i knows its own and its
    in-neighbours' predictions at ``t_0``; a value sent at instant k is known to the out-neighbours at k + 1.
    Greedy: each agent sends the value it knows that the most out-neighbours lack (lowest index on ties). After
    the last instant every agent knows every prediction.
    """
    n = index.shape[0]
    known = np.eye(n, dtype=bool)
    receivers = np.zeros((n, n), dtype=bool)  # [j, i]: i reads j
    for i in range(n):
        known[i, index[i][mask[i]]] = True
        receivers[index[i][mask[i]], i] = True
    schedule = []
    while not known.all():
        lacking = receivers.astype(np.int64) @ (~known).astype(np.int64)  # [j, s]: out-neighbours of j lacking s
        score = np.where(known, lacking, 0)
        send = np.where(score.max(axis=1) > 0, np.argmax(score, axis=1), -1)
        schedule.append(send)
        update = known.copy()
        for j in np.flatnonzero(send >= 0):
            update[receivers[j], send[j]] = True
        known = update
    return np.array(schedule, dtype=np.int64).reshape(-1, n)


def least_peak_inputs(need_x: np.ndarray, need_v: np.ndarray, times: np.ndarray, settling_time: float) -> np.ndarray:
    """The piecewise-constant inputs ``(..., J)`` of least peak over the intervals ``[times[j], times[j+1]]``
    that change the coasted final position by ``need_x`` and the velocity by ``need_v`` (each ``(...)``).

    Bang-bang with one switch: ``σ U`` before the switch interval s, ``-σ U`` after, the value ``u_s`` in it;
    the two landing equations give ``(U, u_s)`` for every s and σ, and the least ``U`` with ``|u_s| <= U`` wins.
    """
    lengths = np.diff(times)  # (J,)
    m0 = lengths  # ∫ dt
    m1 = lengths * (settling_time - times[:-1]) - lengths**2 / 2  # ∫ (T_s - t) dt
    before0, before1 = np.cumsum(m0) - m0, np.cumsum(m1) - m1
    after0, after1 = m0.sum() - before0 - m0, m1.sum() - before1 - m1
    best_u = np.full(need_x.shape, np.inf)
    inputs = np.zeros((*need_x.shape, len(lengths)))
    nx, nv = need_x[..., None], need_v[..., None]
    for sign in (1.0, -1.0):
        a0, a1 = sign * (before0 - after0), sign * (before1 - after1)  # coefficients of U
        det = a0 * m1 - a1 * m0
        with np.errstate(divide="ignore", invalid="ignore"):
            peak = (nv * m1 - nx * m0) / det  # (..., J)
            middle = (a0 * nx - a1 * nv) / det
        ok = np.isfinite(peak) & (peak >= 0) & (np.abs(middle) <= peak * (1 + 1e-12))
        peak = np.where(ok, peak, np.inf)
        s = np.argmin(peak, axis=-1)
        u = np.take_along_axis(peak, s[..., None], axis=-1)[..., 0]
        better = u < best_u
        j = np.arange(len(lengths))
        profile = np.where(j < s[..., None], sign, -sign) * u[..., None]
        profile = np.where(j == s[..., None], np.take_along_axis(middle, s[..., None], axis=-1), profile)
        inputs = np.where(better[..., None], profile, inputs)
        best_u = np.where(better, u, best_u)
    return np.where(np.isfinite(best_u)[..., None], inputs, 0.0)


class BoundedSteerPolicy(SignalPolicy):
    """The gathering law with the least-peak steer, on raw rows, ``plan`` or ``accel`` actions.

    It has memory, so it is called as :class:`~fxc_env.baselines.laws.motion_signals.SignalPolicy` says; agent i's
    action depends only on its own rows, clock and memory, and the offline schedule of the known graph.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` on a fixed strongly connected digraph with
            ideal double-integrator agents and ``obs_mode="raw"`` (``u_max`` allowed: that is its purpose).
        amplitude: the signalling amplitude ε (dimensionless, ``1e-12 <= ε <= 1``,
            :data:`~fxc_env.baselines.laws.motion_signals.AMPLITUDE_RANGE`; None: :data:`DEFAULT_AMPLITUDE`). Under
            ``u_max`` the gathering's own inputs grow like ε (:meth:`gathering_peak`): :meth:`guarantee` says
            whether they stay within the limit for initial states of the configuration's ranges.
        allow_dropout: run under ``link_dropout`` too (off by default: :attr:`LOST_LINK` says what a lost link
            costs; docs: optimality.md, "Lost links").

    Raises:
        ArgumentError naming ``topology``, ``switching``, ``obs_noise``, ``obs_resolution``, ``link_dropout``, ``agent_model``,
        ``obs_mode``, ``action_mode``, ``n_intervals`` or ``amplitude`` for what the law cannot honour.
    """

    NAME: ClassVar[str] = "bounded_steer"
    TITLE: ClassVar[str] = "the bounded-steer law"
    LAW: ClassVar[str] = (
        "flood every relative prediction by small motions (offline schedule), agree on the mid-range point, "
        "then the least-peak (bang-bang, one switch) piecewise-constant steer to it"
    )
    SOURCE: ClassVar[str] = "this project (flooding by small motions; least-peak landing of a double integrator)"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed strongly connected digraph, ideal agents: exact (rounding / ε aside) wherever the least peak from "
        "the end of the gathering is within u_max"
    )

    #: What one lost link costs the law (the refusal of ``link_dropout`` and :meth:`guarantee` say it).
    LOST_LINK: ClassVar[str] = (
        "a lost row reads as a neighbour standing still, a prediction off by its relative value over ε that "
        "the flooding passes on, so the agents steer to different points: worst D(T_s)/D(0) of 20 seeds on a "
        "ring of 20, 2e5 at p = 1e-4"
    )

    def __init__(self, env: Any, amplitude: float | None = None, allow_dropout: bool = False) -> None:
        config = config_of(env, type(self).__name__)
        _refuse_what_it_cannot_honour(config, allow_dropout)
        topology = config.topology
        self.schedule = flooding_schedule(topology.neighbour_index[0], topology.neighbour_mask[0])
        #: The instant at which every agent knows every prediction and starts its steer.
        self.steer_at = len(self.schedule)
        if self.steer_at >= config.n_intervals:
            raise ArgumentError(
                f"n_intervals: the bounded-steer law gathers for {self.steer_at} intervals on this graph and steers "
                f"at least one; got {config.n_intervals}"
            )
        self.amplitude = _amplitude(DEFAULT_AMPLITUDE if amplitude is None else amplitude)
        super().__init__(config)
        self._index, self._mask = topology.neighbour_index[0], topology.neighbour_mask[0]

    def _reset(self, rows: np.ndarray, lead: tuple[int, ...]) -> None:
        n, dim = self.config.n_agents, self.config.dim
        base = initial_offset(rows, self._times[0])  # (..., N, slots, 2, dim): z_j(0) - z_i(0)
        offsets = predicted_register(base, self.config.settling_time)  # (..., N, slots, dim): q_j - q_i
        known = np.zeros((*lead, n, dim), dtype=complex)  # [.., i, s]: q_s - q_i
        agents = np.arange(n)
        for slot in range(self._index.shape[1]):
            real = self._mask[:, slot]
            known[..., agents[real], self._index[real, slot], :] = offsets[..., agents[real], slot, :]
        self._memory = {"base": base, "offsets": offsets, "known": known, "d": np.zeros((*lead, 2, dim))}
        self._memory["inputs"] = np.zeros((*lead, dim, self.config.n_intervals - self.steer_at))

    def _plan(self, k: int, rows: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The plan ``(..., N, 2, dim)`` of every agent at instant k; updates the memory."""
        memory = self._memory
        assert memory is not None
        T_s, eps, T = self.config.settling_time, self.amplitude, self._intervals[k]
        d, known = memory["d"], memory["known"]
        agents = np.arange(self.config.n_agents)
        if 1 <= k <= self.steer_at:  # read what each in-neighbour sent at k - 1: q_s - q_j, plus q_j - q_i
            heard = register_of(read_deviation(rows, memory["base"], d[..., None, :, :], self._times[k]), eps, T_s)
            for slot in range(self._index.shape[1]):
                sender = np.where(self._mask[:, slot], self._index[:, slot], 0)
                sent = self.schedule[k - 1, sender]
                real = self._mask[:, slot] & (sent >= 0)
                value = heard[..., agents[real], slot, :] + memory["offsets"][..., agents[real], slot, :]
                known[..., agents[real], sent[real], :] = value
        if k == self.steer_at:
            memory["inputs"] = self._steer(known, d)
        if k >= self.steer_at:
            u = memory["inputs"][..., k - self.steer_at]  # (..., N, dim)
            plan = np.stack([u * T**2 / 2, u * T], axis=-2)
        else:
            sent = self.schedule[k]
            value = known[..., agents, np.maximum(sent, 0), :]  # (..., N, dim)
            target = np.where((sent >= 0)[:, None, None], deviation_of(value, eps, T_s), advance(d, 0 * d, T))
            plan = signal_plan(target, d, T)
        memory["d"] = advance(d, plan, T)
        return plan

    def _steer(self, known: np.ndarray, d: np.ndarray) -> np.ndarray:
        """The least-peak inputs ``(..., N, dim, J)`` from the deviation ``d`` to the mid-range point."""
        T_s = self.config.settling_time
        goal = (known.real.max(axis=-2) + known.real.min(axis=-2)) / 2
        goal = goal + 1j * (known.imag.max(axis=-2) + known.imag.min(axis=-2)) / 2  # (..., N, dim): point - q_i
        target = deviation_of(goal, 1.0, T_s)  # the deviation at T_s that lands on the point
        t = self._times[self.steer_at]
        need_x = target[..., 0, :] - d[..., 0, :] - (T_s - t) * d[..., 1, :]
        need_v = target[..., 1, :] - d[..., 1, :]
        return least_peak_inputs(need_x, need_v, self._times[self.steer_at :], T_s)

    def gathering_peak(self) -> float:
        """The largest input (m/s²) the gathering can ask at amplitude ε for initial states within the
        configuration's ranges (positions ±P, velocities ±V at their largest draws, or its fixed initial state's).

        Each gathering interval (length T) moves a deviation ``ε (Re c, Im c / T_s)`` to another, ``c`` a
        relative register ``q_s - q_j`` with ``|Re c| <= 2 P + 2 T_s V`` and ``|Im c| <= 2 T_s V``; the plan's end
        inputs (:func:`~fxc_env.core.dynamics.input_from_plan`) are then at most
        ``ε (12 |Re c| / T² + 28 V / T)``, largest on the shortest gathering interval.
        """
        c = self.config
        position, velocity = float(np.max(c.position_range)), float(np.max(c.velocity_range))
        if c.initial_state is not None:
            position, velocity = (float(np.max(np.abs(part))) for part in c.initial_state)
        shortest = float(np.min(self._intervals[: max(self.steer_at, 1)]))
        real = 2.0 * position + 2.0 * c.settling_time * velocity
        return self.amplitude * (12.0 * real / shortest**2 + 28.0 * velocity / shortest)

    def parameters(self) -> dict[str, float]:
        """The design: the gathering's length, the amplitude and the gathering's peak input (:meth:`gathering_peak`)."""
        return {
            "gathering_intervals": float(self.steer_at),
            "amplitude": self.amplitude,
            "gathering_peak": self.gathering_peak(),
        }

    def guarantee(self) -> str:
        return lost_link_guarantee(
            self.config, self._limit_guarantee(), rows_read(self.config, self.steer_at + 1), self.LOST_LINK
        )

    def _limit_guarantee(self) -> str:
        """The guarantee without lost links: exact, and under ``u_max`` where the gathering and the steer fit."""
        exact = f"exact (rounding / ε aside) after gathering for {self.steer_at} intervals"
        if self.config.u_max_choices is None:
            return exact
        limit, peak = min(self.config.u_max_choices), self.gathering_peak()
        if peak > limit:
            largest = self.amplitude * limit / peak
            return (
                f"not exact where the gathering's inputs pass u_max = {limit:g}: at ε = {self.amplitude:g} they reach "
                f"up to {peak:.3g} m/s² for initial states of this configuration's ranges (ε <= {largest:.2g} keeps "
                "them within); exact where they and the least-peak steer to the mid-range point stay within u_max"
            )
        return (
            f"{exact} wherever the least-peak steer to the mid-range point is within u_max = {limit:g} (the "
            f"gathering's inputs stay below {peak:.3g} m/s² for initial states of this configuration's ranges); "
            f"that needs u_max above the input floor by a margin: {LIMIT_MARGIN}"
        )


def _amplitude(value: float) -> float:
    """ε in the signalling laws' range, or an error naming ``amplitude`` with what this law measured past its ends."""
    return signal_amplitude(
        value,
        below="below 1e-12 rounding over ε takes the reads' digits (D(T_s)/D(0) on a ring of 20, K = 200 uniform: "
        "6e-4 at 1e-12, 5e-2 at 1e-14, 5.1 at 1e-16)",
        above="above 1 the energy grows like ε² (8.6e8 x E* at 1 on a ring of 20) and the error again like ε "
        "(2.4e-12 at 10, 1.7e-10 at 596); under u_max the gathering's inputs pass the limit far sooner "
        "(guarantee() says where)",
    )


def _refuse_what_it_cannot_honour(config: Any, allow_dropout: bool = False) -> None:
    name = "BoundedSteerPolicy"
    if config.family is not None:
        raise ArgumentError(f"topology: {name} schedules its flooding offline for one known graph, not a family")
    if config.topology.period != 1 or config.switching != "periodic":
        raise ArgumentError(
            f"switching: {name} reads the offsets of its in-neighbours at t_0 and needs one fixed graph; got a "
            f"period of {config.topology.period} graphs (switching={config.switching!r})"
        )
    adjacency = config.topology.adjacency(0)
    if csgraph.connected_components(adjacency, directed=True, connection="strong")[0] != 1:
        raise ArgumentError(f"topology: {name} needs a strongly connected digraph (every prediction reaches everyone)")
    if config.obs_noise != 0:
        raise ArgumentError(f"obs_noise: {name} reads numbers from exact rows; got obs_noise={config.obs_noise!r}")
    refuse_unless_exact_raw_rows(config, name, allow_dropout, BoundedSteerPolicy.LOST_LINK)


def errors_at_limit_ratios(
    ratios: tuple[float, ...] = LIMIT_RATIOS, seeds: Any = range(20), **graph: Any
) -> dict[float, np.ndarray]:
    """D(T_s)/D(0) ``(len(seeds),)`` of the law per ratio, each seed's ``u_max`` that ratio times its own
    :func:`~fxc_env.core.floors.input_floor` (m/s²; the least limit of any exact controller).

    ``graph``: :func:`fxc_env.make_config` arguments (default: the directed ring of 20, K = 200 uniform, raw
    plans, T_s = 20 s); the initial states are ``np.random.default_rng(seed)``'s, as in ``fxc benchmark``.
    """
    settings = {"topology": "ring", "n_agents": 20, "n_intervals": 200, "schedule": "uniform", **graph}
    config = make_config(**settings, action_mode="plan", obs_mode="raw", u_max=1.0)
    drawn = [ConsensusEngine(config).draw_episode(np.random.default_rng(seed)) for seed in seeds]
    floors = [input_floor(d.x0, d.v0, config.settling_time) for d in drawn]
    errors = {}
    for ratio in ratios:
        engine = ConsensusEngine(config, n_episodes=len(drawn))
        engine.reset_from_draws([EpisodeDraw(d.x0, d.v0, u_max=ratio * f) for d, f in zip(drawn, floors, strict=True)])
        policy = BoundedSteerPolicy(config)
        while not engine.done:
            engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
        errors[ratio] = engine.batch_metrics()["relative_deadline_error"]
    return errors
