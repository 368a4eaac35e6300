"""Exact consensus without knowing the graph: a virtual iteration carried by motion, a recurrence, one steer.

Law, source, proven graph class and refusals: docs: optimality.md, "Without knowing the graph (`graph_agnostic`)".
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws.motion_signals import (
    SignalPolicy,
    advance,
    cycling_outside_roots,
    deviation_of,
    initial_offset,
    predicted_register,
    read_deviation,
    refuse_unless_exact_raw_rows,
    register_of,
    signal_amplitude,
    signal_plan,
    steer_plan,
)
from fxc_env.baselines.laws.policy import lost_link_guarantee, rows_read
from fxc_env.config import config_of
from fxc_env.core import validation
from fxc_env.core.validation import ArgumentError

__all__ = [
    "DEFAULT_AMPLITUDE",
    "DEFAULT_ANNOUNCE",
    "DEFAULT_RANK_TOLERANCE",
    "GraphAgnosticPolicy",
    "listening_values",
    "recurrence_limit",
]

#: Default signalling amplitude ε: three times the signalling law's (its window is longer and its rank test
#: wants the cleaner reads; the ring N = 20 then ends near 5e-10 at 2.4 x E*, the signalling energy ~1e-2 of it).
DEFAULT_AMPLITUDE = 3e-6

#: Default rank-test tolerance: a Hankel singular value below this fraction of the differences' norm
#: counts as zero (reading errors at the default amplitude are about 1e-10 of the registers).
DEFAULT_RANK_TOLERANCE = 1e-8

#: The rank tolerances the law accepts, ``(smallest, largest)``. Below float64's rounding unit (1.1e-16) no
#: singular value of real reads ever counts as zero, so the test never certifies a recurrence and every agent
#: listens on to the one-channel window: still exact, at more energy (ring N = 20, K = 200 uniform: 5e-10 at
#: 2.47 x E* from 1e-12 down, 3.2e-10 at 1.95 x E* at 1e-10 to 1e-6). Above 1e-6 it takes reading errors for a
#: kernel and finds a wrong limit (random N = 20: 4.7e-7 at 1e-4; ring N = 20: 0.35 at 1e-2, 13 at 0.99).
RANK_TOLERANCE_RANGE = (1e-16, 1e-6)


#: Default instant of the pre-steer announcement ``k_a`` (1 s at the uniform K = 200): late enough for a fast
#: iteration to have settled, early enough for the pre-steer to start near the E*-optimal path.
DEFAULT_ANNOUNCE = 10

#: The amplitude η of the announcement: the deviation ``η (Re a, Im a / T_s)`` at ``t_{k_a + 1}`` carries ``a_i``.
ANNOUNCE = 1e-5

#: Bits of an announced aim below its sender's loudness ``|c_i(k_a)|``: the aim is rounded to the power-of-two grid
#: ``2^(ceil(log2 |c_i(k_a)|) - AIM_BITS + 1)``, a reader rounds to ``2^(ceil(log2 |ĉ_i(k_a)|) - AIM_BITS)`` from its own
#: read of the loudness. The reader's grid divides the sender's wherever the read is within a factor 2, so it holds the
#: very aim chosen, and it is ``2^-13 |c_i(k_a)|`` or coarser, far above the announcement's reading error
#: (``1e-16 |z| / η``, about 1e-10 of the state's scale). Every quantity is relative to the state: the law is
#: scale-free (the same D(T_s)/D(0) for ``x(0), v(0) -> c x(0), c v(0)``).
AIM_BITS = 12

#: A reader takes an in-neighbour for silent (aim 0) where the register it heard at ``k_a`` is below this fraction of
#: the reader's own register spread ``max_j |w_j(0) - w_i(0)|``: an agent with no in-neighbour never moves, and what
#: its readers hear of it is rounding (about 1e-9 of the state's scale), which no relative grid rounds away.
SILENT = 2.0**-16

#: The pre-steer trusts the iterate only when its latest changes are below this fraction of it
#: (weight ``1 - change / (RHO |c|)``, none above): on a ring the iterate wanders and nobody pre-steers.
RHO = 0.2


def on_aim_grid(aim: np.ndarray, loudness: np.ndarray, coarser: int) -> np.ndarray:
    """``aim`` ``(..., dim)`` rounded to the grid ``2^(ceil(log2 loudness) - AIM_BITS + coarser)`` of its sender's
    loudness ``(...)`` (zero where the loudness is zero)."""
    with np.errstate(divide="ignore"):
        exponent = np.ceil(np.log2(np.where(loudness > 0, loudness, 1.0))) - AIM_BITS + coarser
    grid = np.ldexp(1.0, exponent.astype(np.int64))[..., None]
    rounded = grid * (np.round(aim.real / grid) + 1j * np.round(aim.imag / grid))
    return np.where(loudness[..., None] > 0, rounded, 0.0)


def presteer_aim(values: np.ndarray) -> np.ndarray:
    """The aim ``a_i`` ``(..., dim)`` from the latest three values ``c_i(k_a - 1 .. k_a + 1)`` ``(..., 3, dim)``: the
    iterate weighted by how settled it looks (at most ``1.25 |c_i(k_a)|``), on the grid of its loudness
    ``|c_i(k_a)|`` one step coarser than its readers' (:data:`AIM_BITS`)."""
    change = np.max(np.sqrt(np.sum(np.abs(np.diff(values, axis=-2)) ** 2, axis=-1)), axis=-1)  # (...)
    size = np.sqrt(np.sum(np.abs(values[..., -1, :]) ** 2, axis=-1))
    weight = np.clip(1.0 - change / np.maximum(RHO * size, 1e-300), 0.0, 1.0)
    loudness = np.sqrt(np.sum(np.abs(values[..., -2, :]) ** 2, axis=-1))
    return on_aim_grid(weight[..., None] * values[..., -1, :], loudness, 1)


def heard_aim(
    deviation: np.ndarray, heard: np.ndarray, spread: np.ndarray, amplitude: float, settling_time: float
) -> np.ndarray:
    """The neighbours' aims ``(..., slots, dim)`` from their deviations at ``t_{k_a + 1}``, ``η a_j + ε c_j(k_a)``
    with ``c_j(k_a)`` already ``heard``: on the grid of the heard loudness ``|c_j(k_a)|`` (:data:`AIM_BITS`), exactly
    the aims they chose; zero for a neighbour heard below :data:`SILENT` times the reader's register ``spread``
    ``(...)``."""
    aim = register_of(deviation - deviation_of(heard, amplitude, settling_time), ANNOUNCE, settling_time)
    loudness = np.sqrt(np.sum(np.abs(heard) ** 2, axis=-1))  # (..., slots)
    loudness = np.where(loudness > SILENT * spread[..., None], loudness, 0.0)
    return on_aim_grid(aim, loudness, 0)


def register_spread(base: np.ndarray, mask: np.ndarray, settling_time: float) -> np.ndarray:
    """An agent's register spread ``max_j |w_j(0) - w_i(0)|`` ``(...)`` over its in-neighbours, from its first rows."""
    difference = np.sqrt(np.sum(np.abs(predicted_register(base, settling_time)) ** 2, axis=-1))  # (..., slots)
    return np.max(np.where(mask, difference, 0.0), axis=-1, initial=0.0)


def presteer_path(aim: np.ndarray, start: float, t: float, settling_time: float) -> np.ndarray:
    """The pre-steer's deviation ``(..., 2, dim)`` at ``t >= start``: the minimum-energy path from the announcement
    ``η (Re a, Im a / T_s)`` at ``start`` to ``(Re a, Im a / T_s)`` at ``T_s`` (a closed-form cubic)."""
    begin = deviation_of(aim, ANNOUNCE, settling_time)
    plan = steer_plan(deviation_of(aim, 1.0, settling_time), begin, start, t - start, settling_time)
    return advance(begin, plan, t - start)


def _announce_instant(value: Any, listening: int, full_listening: int, n_intervals: int) -> int | None:
    """The announcement instant: ``value`` checked (0: no pre-steer), or the default where the window leaves room."""
    latest = listening - 4  # at least one value after the held interval before the steer
    if value is None:
        default = min(DEFAULT_ANNOUNCE, latest)
        return default if default >= 2 and full_listening <= n_intervals else None
    value = validation.integer("announce_at", value, 0)
    if value == 0:
        return None
    if not 2 <= value <= latest:
        raise ArgumentError(
            f"announce_at: the pre-steer announcement instant, 0 (none) or in [2, {latest}] "
            f"(inside the listening window of {listening} values); got {value}"
        )
    return value


def listening_values(max_agents: int, channels: int = 1) -> int:
    """``L = max_agents + ceil((max_agents + 1) / C) + 1``: the values ``w_i(0..L-1)`` recorded before the steer.

    C channels give a Hankel matrix of ``C (L - 1 - d)`` rows, one more than its ``d + 1`` columns for every
    degree ``d <= max_agents - 1``; one channel: ``2 max_agents + 2`` (Yuan et al.).
    """
    return max_agents + -(-(max_agents + 1) // channels) + 1


def recurrence_limit(
    values: np.ndarray, max_degree: int, tolerance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The limit of each recorded sequence from its shortest recurrence (Yuan et al. 2013).

    Args:
        values: ``(M, C, L)`` real: M agents' recorded sequences, C channels each that share one
            recurrence (the same iteration on different initial values), L values.
        max_degree: the largest degree ``d`` of ``p`` tried (``N - 1`` at most).
        tolerance: a singular value below ``tolerance`` times the differences' norm is zero.

    Returns:
        ``(limits (M, C), degrees (M,), certified (M,))``: ``Σ_m β_m w(k + m) / Σ_m β_m`` on the latest
        window; the degree found (the smallest-σ degree when no Hankel passes); and whether the kernel is backed
        by more windows than unknowns, counting only the numerically independent channels.
    """
    M, C, L = values.shape
    diffs = np.diff(values, axis=-1)  # (M, C, L - 1)
    scale = np.sqrt(np.sum(diffs**2, axis=(1, 2)))  # (M,)
    safe_scale = np.where(scale > 0, scale, 1.0)
    channel_sigma = np.linalg.svd(diffs, compute_uv=False)  # (M, min(C, L - 1))
    independent = np.sum(channel_sigma > tolerance * safe_scale[:, None], axis=-1)
    degrees = np.full(M, -1, dtype=np.int64)
    kernels: list[np.ndarray | None] = [None] * M
    best = np.full(M, np.inf)
    fallback: list[tuple[int, np.ndarray] | None] = [None] * M
    for d in range(max_degree + 1):
        todo = np.flatnonzero(degrees < 0)
        if len(todo) == 0 or C * (L - 1 - d) < d + 2:  # done, or too few windows to tell a kernel
            break
        rows = L - 1 - d  # windows per channel
        window = np.lib.stride_tricks.sliding_window_view(diffs[todo], d + 1, axis=-1)  # (m, C, rows, d + 1)
        _, sigma, vh = np.linalg.svd(window.reshape(len(todo), C * rows, d + 1), full_matrices=False)
        relative = sigma[:, -1] / safe_scale[todo]
        for n, agent in enumerate(todo):
            if relative[n] <= tolerance:
                degrees[agent] = d
                kernels[agent] = vh[n, -1]
            elif relative[n] < best[agent]:
                best[agent] = relative[n]
                fallback[agent] = (d, vh[n, -1])
    certified = (degrees >= 0) & (np.maximum(independent, 1) * (L - 1 - np.maximum(degrees, 0)) >= degrees + 2)
    limits = np.empty((M, C))
    for agent in range(M):
        if degrees[agent] < 0:
            degrees[agent], kernels[agent] = fallback[agent]
        beta = kernels[agent]
        d = int(degrees[agent])
        latest = values[agent, :, L - 1 - d :]  # w(k + m), m = 0..d, on the latest window
        limits[agent] = latest @ beta / np.sum(beta)
    return limits, degrees, certified


class GraphAgnosticPolicy(SignalPolicy):
    """The graph-agnostic law on the local observation, raw rows, ``plan`` or ``accel`` actions.

    It has memory, so it is called as :class:`~fxc_env.baselines.laws.motion_signals.SignalPolicy` says; agent i's
    action depends only on its own observations and memory.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` on a fixed digraph with ideal
            double-integrator agents, ``obs_mode="raw"``, and ``K >= 2 max_agents + 1``.
        max_agents: an upper bound on N, the law's one prior (None: the environment's N). It sets the
            listening window (:func:`listening_values`; ``2 max_agents + 2`` values where the register parts are dependent).
        amplitude: the signalling amplitude ε (dimensionless, ``1e-12 <= ε <= 1``,
            :data:`~fxc_env.baselines.laws.motion_signals.AMPLITUDE_RANGE`; None: :data:`DEFAULT_AMPLITUDE`).
        rank_tolerance: the rank test's relative tolerance (``1e-16 <= tol <= 1e-6``, :data:`RANK_TOLERANCE_RANGE`;
            None: :data:`DEFAULT_RANK_TOLERANCE`).
        announce_at: the instant ``k_a`` of the pre-steer announcement, in ``[2, L - 4]``, or 0 for none (None:
            :data:`DEFAULT_ANNOUNCE` or ``L - 4`` if earlier, none where K has no room for the held interval).
        allow_dropout: run under ``link_dropout`` too (off by default: :attr:`LOST_LINK` says what a lost link
            costs; docs: optimality.md, "Lost links").

    Raises:
        ArgumentError naming ``topology``, ``switching``, ``u_max``, ``obs_noise``, ``obs_resolution``, ``link_dropout``,
        ``agent_model``, ``obs_mode``, ``action_mode``, ``max_agents``, ``n_intervals``, ``amplitude``,
        ``rank_tolerance`` or ``announce_at`` for what the law cannot honour.
    """

    NAME: ClassVar[str] = "graph_agnostic"
    TITLE: ClassVar[str] = "the graph-agnostic law"
    LAW: ClassVar[str] = (
        "virtual iteration w <- D⁻¹A w on registers w_i = p_i, carried at amplitude ε by motions read from own rows; "
        "each agent's shortest recurrence of its own differences (block Hankel rank test over its register parts, "
        "about 1.5 max_agents values) "
        "gives the limit; a pre-steer toward the settled iterate, announced on a grid relative to its loudness; then one "
        "minimum-energy steer"
    )
    SOURCE: ClassVar[str] = (
        "Yuan, Stan, Shi, Barahona & Gonçalves 2013 (decentralised minimum-time consensus), carried by this "
        "project's signalling through small motions"
    )
    GRAPH_CLASS: ClassVar[str] = (
        "fixed digraph with a directed spanning tree whose cycles all lie in its root set (strongly connected, or "
        "an acyclic rest) and at most max_agents agents, ideal agents, graph unknown: "
        "exact up to rounding / ε at ξᵀ p (the mean prediction where ξ is uniform)"
    )
    #: What one lost link costs the law (the refusal of ``link_dropout`` and :meth:`guarantee` say it).
    LOST_LINK: ClassVar[str] = (
        "a lost row puts a wrong value in the reader's recurrence, so a wrong limit or a failed rank test: "
        "worst D(T_s)/D(0) of 20 seeds on a ring of 20, 0.17 at p = 1e-4, 2e11 at 1e-2"
    )

    def __init__(
        self,
        env: Any,
        max_agents: int | None = None,
        amplitude: float | None = None,
        rank_tolerance: float | None = None,
        announce_at: int | None = None,
        allow_dropout: bool = False,
    ) -> None:
        config = config_of(env, type(self).__name__)
        _refuse_what_it_cannot_honour(config, allow_dropout)
        n = config.n_agents
        max_agents = validation.integer("max_agents", n if max_agents is None else max_agents, 1)
        if max_agents < n:
            raise ArgumentError(
                f"max_agents: an upper bound on the number of agents, at least the environment's N = {n}; "
                f"got {max_agents}"
            )
        amplitude = _amplitude(DEFAULT_AMPLITUDE if amplitude is None else amplitude)
        rank_tolerance = validation.in_range(
            "rank_tolerance",
            DEFAULT_RANK_TOLERANCE if rank_tolerance is None else rank_tolerance,
            *RANK_TOLERANCE_RANGE,
            below="below float64's rounding unit no recurrence is ever certified",
            above="above, reading errors pass for a kernel and the limit is wrong (ring N = 20: 0.35 at 1e-2)",
        )
        #: Values ``w_i(0..L-1)`` recorded with the ``2 dim`` register parts as channels.
        self.listening = listening_values(max_agents, 2 * config.dim)
        #: The one-channel window ``2 max_agents + 2``: agents whose register parts turn out dependent listen on.
        self.full_listening = listening_values(max_agents)
        #: The instant ``k_a`` of the pre-steer announcement (None: none); the iteration holds one interval there.
        self.announce_at = _announce_instant(announce_at, self.listening, self.full_listening, config.n_intervals)
        hold = 0 if self.announce_at is None else 1
        #: The instants of the steer: ``L - 2`` (plus the held interval), and that of the one-channel window.
        self.steer_at, self.full_at = self.listening - 2 + hold, self.full_listening - 2 + hold
        if self.full_at + 1 > config.n_intervals:
            raise ArgumentError(
                f"n_intervals: the graph-agnostic law may listen {self.full_listening - 2} intervals (2 max_agents, "
                f"max_agents = {max_agents}) and steers at least one; got {config.n_intervals}"
            )
        self.max_agents = max_agents
        self.amplitude = amplitude
        self.rank_tolerance = rank_tolerance
        super().__init__(config)
        #: Per agent of the last episode batch, the degree of the recurrence its rank test found ``(..., N)``.
        self.degrees: np.ndarray | None = None

    # ----------------------------------------------------------------------------- acting
    def _reset(self, rows: np.ndarray, lead: tuple[int, ...]) -> None:
        dim, slots = self.config.dim, self.layout.slots
        self._memory = {
            "base": np.zeros((*lead, slots, 2, dim)),  # z_j(0) - z_i(0) per row slot
            "history": np.zeros((*lead, self.full_listening, dim), dtype=complex),  # c_i(n) = w_i(n) - w_i(0)
            "late": np.zeros(lead, dtype=bool),  # listening on to the one-channel window
            "goal": np.zeros((*lead, dim), dtype=complex),  # w* - w_i(0), known at the steer
            "d": np.zeros((*lead, 2, dim)),  # own deviation from coasting
            "aim": np.zeros((*lead, dim), dtype=complex),  # a_i: own pre-steer aim (a register, on the grid)
            "heard_aim": np.zeros((*lead, slots, dim), dtype=complex),  # a_j per row slot
            "heard": np.zeros((*lead, slots, dim), dtype=complex),  # c_j of the latest read per row slot
        }
        self.degrees = None

    def _value_index(self, k: int) -> int:
        """The index n of the value ``c_j(n)`` the rows carry at instant k (one less after the held interval)."""
        return k if self.announce_at is None or k <= self.announce_at else k - 1

    def _plan(self, k: int, rows: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The plan ``(a_x, a_v)`` ``(..., N, 2, dim)`` of every agent at instant k; updates the memory."""
        _, mask, _ = self.layout.split(obs)
        memory = self._memory
        assert memory is not None
        T_s, eps, k_a = self.config.settling_time, self.amplitude, self.announce_at
        t, T = self._times[k], self._intervals[k]
        d, history, late = memory["d"], memory["history"], memory["late"]
        n = self._value_index(k)
        if k <= self.steer_at or (k <= self.full_at and late.any()):
            if k == 0:  # nobody has deviated yet: the rows give z_j(0) - z_i(0)
                memory["base"] = initial_offset(rows, t)
            deviation = read_deviation(rows, memory["base"], d[..., None, :, :], t)
            if k_a is not None and k == k_a + 1:  # the held interval: η a_j + ε c_j(k_a), a_j on the grid
                spread = register_spread(memory["base"], mask, T_s)
                memory["heard_aim"] = heard_aim(deviation, memory["heard"], spread, eps, T_s)
            else:
                if k_a is not None and k > k_a:
                    deviation = deviation - presteer_path(memory["heard_aim"], self._times[k_a + 1], t, T_s)
                self._iterate(k, n, deviation, mask)
        if k_a is not None and k == k_a:
            memory["aim"] = presteer_aim(history[..., max(k_a - 1, 0) : k_a + 2, :])
        if k == self.steer_at:
            certified = self._find_goal(self.listening, np.ones(late.shape, dtype=bool))
            # Dependent register parts (every velocity equal, say) leave too few independent windows: those
            # agents listen on to the one-channel window; every agent sees such initial states alike.
            late[...] = ~certified & (self.full_at > self.steer_at)
        elif k == self.full_at and late.any():
            self._find_goal(self.full_listening, late)
        steering = (k >= self.full_at) | ((k >= self.steer_at) & ~late)
        # Signal c_i(n + 1) (the deviation at t_{k+1}: the pre-steer path plus ε (Re c, Im c / T_s)), or steer:
        # the piece over [t_k, t_k+1] of the minimum-energy input to w* - w_i(0) at T_s.
        plan = steer_plan(deviation_of(memory["goal"], 1.0, T_s), d, t, T, T_s)
        if not steering.all():
            target = deviation_of(history[..., min(n + 1, self.full_listening - 1), :], eps, T_s)
            if k_a is not None and k == k_a:
                target = deviation_of(history[..., k_a, :], eps, T_s) + deviation_of(memory["aim"], ANNOUNCE, T_s)
            elif k_a is not None and k > k_a:
                target = target + presteer_path(memory["aim"], self._times[k_a + 1], self._times[k + 1], T_s)
            plan = np.where(steering[..., None, None], plan, signal_plan(target, d, T))
        memory["d"] = advance(d, plan, T)
        return plan

    def _iterate(self, k: int, n: int, deviation: np.ndarray, mask: np.ndarray) -> None:
        """One step of the virtual iteration: ``c_i(n + 1)`` from the neighbours' ``c_j(n)`` read at instant k."""
        memory = self._memory
        assert memory is not None
        history = memory["history"]
        heard = register_of(deviation, self.amplitude, self.config.settling_time)
        if k == 0:
            heard = np.zeros_like(heard)  # c_j(0) = 0 exactly
        memory["heard"] = heard
        registers = predicted_register(memory["base"], self.config.settling_time) + heard  # w_j(n) - w_i(0)
        degree = np.sum(mask, axis=-1)[..., None]
        mean = np.sum(mask[..., None] * registers, axis=-2) / np.maximum(degree, 1.0)
        if n + 1 < self.full_listening:
            history[..., n + 1, :] = np.where(degree > 0, mean, history[..., n, :])

    def _find_goal(self, length: int, agents: np.ndarray) -> np.ndarray:
        """The limit of the chosen agents' ``(..., N)`` first ``length`` recorded values (their shortest
        recurrence) into their goal; returns whether each agent's recurrence is certified ``(..., N)``."""
        memory = self._memory
        assert memory is not None
        history = memory["history"][..., :length, :][agents]  # (M, L, dim)
        dim = history.shape[-1]
        values = np.moveaxis(np.concatenate([history.real, history.imag], axis=-1), -1, -2)  # (M, 2 dim, L)
        limits, degrees, certified = recurrence_limit(values, self.max_agents - 1, self.rank_tolerance)
        memory["goal"][agents] = limits[:, :dim] + 1j * limits[:, dim:]
        if self.degrees is None:
            self.degrees = np.full(agents.shape, -1, dtype=np.int64)
        self.degrees[agents] = degrees
        result = np.ones(agents.shape, dtype=bool)
        result[agents] = certified
        return result

    # ----------------------------------------------------------------------------- describing
    def parameters(self) -> dict[str, float]:
        """The design: the prior, the window, the steer's start, the amplitude and the rank tolerance."""
        return {
            "max_agents": float(self.max_agents),
            "listening_values": float(self.listening),
            "full_listening_values": float(self.full_listening),
            "announce_at": float(0 if self.announce_at is None else self.announce_at),
            "steer_start_s": float(self._times[self.steer_at]),
            "amplitude": self.amplitude,
            "rank_tolerance": self.rank_tolerance,
        }

    def guarantee(self) -> str:
        t_l = self._times[self.steer_at]
        bound = (self.config.settling_time / (self.config.settling_time - t_l)) ** 3
        exact = (
            f"graph unknown: exact (rounding / ε aside) for N <= max_agents = {self.max_agents} after listening "
            f"{self.steer_at} intervals (t_L = {t_l:.3g} s; {self.full_at} when the register parts are dependent), "
            f"then one minimum-energy steer (at most about E* x {bound:.3g} where ξ is uniform; less where a "
            "settled iterate lets it pre-steer)"
        )
        reads = rows_read(self.config, self.full_at + 1)  # from t_0 to the longest window's end
        return lost_link_guarantee(self.config, exact, reads, self.LOST_LINK)


def _refuse_what_it_cannot_honour(config: Any, allow_dropout: bool = False) -> None:
    name = "GraphAgnosticPolicy"
    if config.family is not None:
        raise ArgumentError(
            f"topology: {name} needs one fixed graph for its recurrence; a family draws a new graph per episode"
        )
    if config.topology.period != 1:
        raise ArgumentError(
            f"topology: {name} finds the recurrence of one fixed iteration; a switching period of "
            f"{config.topology.period} graphs changes the iteration every interval"
        )
    if config.switching != "periodic":
        raise ArgumentError(f"switching: {name} needs one fixed graph, not switching={config.switching!r}")
    if config.u_max_choices is not None:
        raise ArgumentError(f"u_max: {name} plans exact changes and cannot honour an input limit")
    if config.obs_noise != 0:
        raise ArgumentError(
            f"obs_noise: {name} reads numbers from exact relative measurements and its rank test needs them; "
            f"got obs_noise={config.obs_noise!r}"
        )
    refuse_unless_exact_raw_rows(config, name, allow_dropout, GraphAgnosticPolicy.LOST_LINK)
    cycling = cycling_outside_roots(config.topology)
    if len(cycling):
        listed = ", ".join(str(int(i)) for i in cycling[:8]) + (", ..." if len(cycling) > 8 else "")
        raise ArgumentError(
            f"topology: {name} is exact where every cycle of the graph lies in its root set (strongly connected, or "
            f"the rest acyclic: trees, paths, stars); agents [{listed}] lie on a cycle outside it, whose slowly "
            "decaying modes its rank test cannot tell from reading errors (single-root N = 40: D(T_s)/D(0) up to "
            "1.8e-6)"
        )


def _amplitude(value: Any) -> float:
    """ε in the signalling laws' range, or an error naming ``amplitude`` with what this law measured past its ends."""
    return signal_amplitude(
        value,
        below="below 1e-12 rounding over ε takes the reads' digits and the rank test fails (D(T_s)/D(0), K = 200 "
        "uniform, rings of 6 and 20, random N = 20: up to 2e-3 at 1e-12, 0.2 at 1e-14, 2.7e14 at 1e-16; NaN actions "
        "at 1e-300)",
        above="above 1 the energy grows like ε² (1e8 to 1.2e9 x E* at 1) and the error again like ε (6e-9 at 1e4, "
        "6e87 at 1e100)",
    )
