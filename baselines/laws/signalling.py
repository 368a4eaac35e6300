"""A law on the energy-accuracy frontier: agree on the target by small motions, then steer once.

Law, source, proven graph class and refusals: docs: optimality.md, "Signalling through motion (`signalling`)".
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws.motion_signals import (
    AMPLITUDE_RANGE,
    SignalPolicy,
    advance,
    averaging_weights,
    deviation_of,
    initial_offset,
    leja_order,
    predicted_register,
    read_deviation,
    refuse_unless_exact_raw_rows,
    register_eigenvalues,
    register_of,
    signal_amplitude,
    signal_plan,
    steer_plan,
    union_graph,
)
from fxc_env.baselines.laws.policy import lost_link_guarantee, rows_read
from fxc_env.config import config_of
from fxc_env.core.optimality import root_set
from fxc_env.core.validation import ArgumentError, boolean

#: Default signalling amplitude ε: a deviation of 1e-6 of the register, read about 1e10 above the
#: float64 rounding of a row (1e-16 relative), at an energy about 1e-12 of the state scale squared.
DEFAULT_AMPLITUDE = 1e-6


class SignallingPolicy(SignalPolicy):
    """The signalling law on the local observation, raw rows, ``plan`` or ``accel`` actions.

    It has memory, so it is called as :class:`~fxc_env.baselines.laws.motion_signals.SignalPolicy` says; agent i's
    action depends only on its own observations and memory.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` on a fixed digraph with a
            directed spanning tree, or a periodic set whose union has one, with ideal double-integrator
            agents, ``obs_mode="raw"`` and K at least the agreement's intervals.
        amplitude: the signalling amplitude ε (dimensionless, in :data:`AMPLITUDE_RANGE`, ``1e-12 <= ε <= 1``;
            None: :data:`DEFAULT_AMPLITUDE`). Under ``obs_noise`` the law runs only with an explicit amplitude
            (the frontier point is the user's choice).
        allow_limit: run under ``u_max`` too (off by default): exact wherever every input stays within the
            limit, the clip breaks the landing elsewhere (docs: optimality.md, "How far from optimal").
        allow_dropout: run under ``link_dropout`` too (off by default: :attr:`LOST_LINK` says what a lost link
            costs; docs: optimality.md, "Lost links").

    Raises:
        ArgumentError naming ``topology``, ``switching``, ``u_max``, ``obs_noise``, ``obs_resolution``, ``link_dropout``, ``agent_model``,
        ``obs_mode``, ``n_intervals`` or ``amplitude`` for what the design cannot honour.
    """

    NAME: ClassVar[str] = "signalling"
    TITLE: ClassVar[str] = "the signalling law"
    LAW: ClassVar[str] = (
        "read neighbours' deviations from coasting as numbers; exact consensus q <- (I - Ŵ/μ) q on registers "
        "q_i = p_i (μ over the eigenvalues of Ŵ in Leja order), then on the known correction to the unweighted mean, "
        "signalled at amplitude ε; then one minimum-energy steer to the agreed mean prediction"
    )
    SOURCE: ClassVar[str] = "this project (signalling through small motions, then one minimum-energy steer)"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed digraph with a directed spanning tree (or periodic set whose union has one), ideal agents: the roots' "
        "unweighted mean of the predictions (all agents' when strongly connected), up to rounding / ε"
    )

    #: What one lost link costs the law (the refusal of ``link_dropout`` and :meth:`guarantee` say it).
    LOST_LINK: ClassVar[str] = (
        "a lost row reads as a neighbour standing still, a register off by its whole relative prediction over "
        "ε, which the exact factors spread: worst D(T_s)/D(0) of 20 seeds on a ring of 20, 3e5 at p = 1e-4"
    )

    def __init__(
        self, env: Any, amplitude: float | None = None, allow_limit: bool = False, allow_dropout: bool = False
    ) -> None:
        config = config_of(env, type(self).__name__)
        boolean("allow_limit", allow_limit)
        _refuse_what_it_cannot_honour(config, allow_limit, allow_dropout)
        if config.obs_noise != 0 and amplitude is None:
            raise ArgumentError(
                f"obs_noise: {type(self).__name__} reads numbers from exact relative measurements; with noise σ each "
                "read is off by σ / ε, amplified by the exact-consensus factors (a directed ring N = 20 at σ = 1e-6: "
                "deadline error 2.8e-2 at 14 x E*, 2.8e-4 at 1.3e5 x E*); give amplitude=ε to run it anyway, "
                f"got obs_noise={config.obs_noise!r}"
            )
        self.amplitude = _amplitude(DEFAULT_AMPLITUDE if amplitude is None else amplitude)
        topology = config.topology
        n, m = config.n_agents, topology.period
        #: ``ξ`` ``(N,)``: the weights of the first stage's consensus value ``ξᵀ q(0)``.
        self.xi = averaging_weights(topology)
        self.roots = root_set(topology)
        #: The second stage (moving ``ξᵀ q`` to the roots' unweighted mean) is needed unless ``ξ`` is uniform.
        self.two_stages = bool(np.max(np.abs(self.xi[self.roots] * len(self.roots) - 1.0)) > 1e-12)
        self.eigenvalues = leja_order(register_eigenvalues(topology))
        degree = np.asarray(union_graph(topology).sum(axis=1)).ravel()
        self._gain = 1.0 / (degree + 1.0)  # the row weight of W-hat = (D + I)^{-1} L
        # gamma_i = -(1/R - xi_i) o_i / xi_i on the roots (0 elsewhere): xi^T gamma = -sum_R (1/R - xi_i) o_i.
        self._correction = np.zeros(n)
        self._correction[self.roots] = -(1.0 / len(self.roots) - self.xi[self.roots]) / self.xi[self.roots]
        #: Register updates (one per nonzero eigenvalue of Ŵ, per stage) and the intervals of the agreement:
        #: one period per update; the steer starts at the last update.
        self.updates = (n - 1) * (2 if self.two_stages else 1)
        self.agreement_intervals = m * self.updates
        if self.agreement_intervals > config.n_intervals:
            raise ArgumentError(
                f"n_intervals: the signalling law needs at least {self.agreement_intervals} intervals "
                f"({m} per update x {self.updates} updates), got {config.n_intervals}"
            )
        super().__init__(config)
        # The union in-neighbours of every agent, and where slot s of graph g puts its row among them.
        union = union_graph(topology)
        union_neighbours = [np.sort(union[[i], :].indices) for i in range(n)]
        self._union_slots = max(1, max(len(u) for u in union_neighbours))
        self._union_mask = np.zeros((n, self._union_slots))
        for i, u in enumerate(union_neighbours):
            self._union_mask[i, : len(u)] = 1.0
        index, mask = topology.neighbour_index, topology.neighbour_mask
        self._slot_map = np.full((m, n, self.layout.slots), -1, dtype=np.int64)
        for g in range(m):
            for i in range(n):
                for s in np.flatnonzero(mask[g, i]):
                    self._slot_map[g, i, s] = int(np.searchsorted(union_neighbours[i], index[g, i, s]))

    # ----------------------------------------------------------------------------- acting
    def _reset(self, rows: np.ndarray, lead: tuple[int, ...]) -> None:
        dim = self.config.dim
        self._memory = {
            "base": np.zeros((*lead, self._union_slots, 2, dim)),  # z_j(0) - z_i(0) per union neighbour
            "heard": np.zeros((*lead, self._union_slots, dim), dtype=complex),  # c_j as last read
            "c": np.zeros((*lead, dim), dtype=complex),  # own register change (stage 1)
            "second": np.zeros((*lead, dim), dtype=complex),  # own register value (stage 2)
            "d": np.zeros((*lead, 2, dim)),  # own deviation from coasting
        }

    def _plan(self, k: int, rows: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The plan ``(a_x, a_v)`` ``(..., N, 2, dim)`` of every agent at instant k; updates the memory."""
        memory = self._memory
        assert memory is not None
        c = self.config
        m, T_s, eps = c.topology.period, c.settling_time, self.amplitude
        t, T = self._times[k], self._intervals[k]
        d = memory["d"]
        last_update = self.agreement_intervals - 1
        n_first = self.config.n_agents - 1
        if k <= last_update:
            self._read(k, rows)
            if k % m == m - 1:  # the period's reads are in: one register update
                update = k // m
                heard, mine = memory["heard"], (memory["c"] if update < n_first else memory["second"])
                if update < n_first:  # stage 1: differences of the unknown q_i(0) plus changes
                    initial = predicted_register(memory["base"], T_s)
                    differences = initial + heard - mine[..., None, :]
                else:  # stage 2: registers of known values
                    differences = heard - mine[..., None, :]
                total = np.sum(self._union_mask[:, :, None] * differences, axis=-2)
                step = mine + (self._gain[:, None] / self.eigenvalues[update % n_first]) * total
                if update < n_first:
                    memory["c"] = step
                    if update == n_first - 1:  # o_i = xi^T q - q_i is known: start stage 2 at gamma_i
                        memory["second"] = self._correction[:, None] * step
                else:
                    memory["second"] = step
        stage_two = self.two_stages and k >= m * n_first - 1
        register = memory["second"] if stage_two and k < last_update else memory["c"]
        if k >= last_update and self.two_stages:
            register = memory["c"] + memory["second"]  # o_i + xi^T gamma: the roots' mean minus q_i(0)
        if k < last_update:  # signal: set the deviation at t_{k+1} to ε (Re c, Im c / T_s)
            plan = signal_plan(deviation_of(register, eps, T_s), d, T)
        else:  # steer: the piece over [t_k, t_k+1] of the minimum-energy input to the agreed point at T_s
            plan = steer_plan(deviation_of(register, 1.0, T_s), d, t, T, T_s)  # p̄ - p_i, wanted at T_s
        memory["d"] = advance(d, plan, T)
        return plan

    def _read(self, k: int, rows: np.ndarray) -> None:
        """Store each in-neighbour's first relative state, or read its register change from its row."""
        memory = self._memory
        assert memory is not None
        c = self.config
        m, T_s, eps, t = c.topology.period, c.settling_time, self.amplitude, self._times[k]
        slot_map = self._slot_map[k % m]
        base, d = memory["base"], memory["d"]
        for s in range(self.layout.slots):
            agents = np.flatnonzero(slot_map[:, s] >= 0)
            if len(agents) == 0:
                continue
            where = slot_map[agents, s]
            row = rows[..., agents, s, :, :]  # (..., A, 2, dim)
            if k < m:  # first period: nobody has deviated yet; the row is Φ(t_k) (z_j(0) - z_i(0))
                base[..., agents, where, :, :] = initial_offset(row, t)
                continue
            deviation = read_deviation(row, base[..., agents, where, :, :], d[..., agents, :, :], t)
            memory["heard"][..., agents, where, :] = register_of(deviation, eps, T_s)

    # ----------------------------------------------------------------------------- describing
    def parameters(self) -> dict[str, float]:
        """The design: amplitude, register updates, agreement intervals, the steer's start and the smallest |μ|."""
        return {
            "amplitude": self.amplitude,
            "updates": float(self.updates),
            "agreement_intervals": float(self.agreement_intervals),
            "steer_start_s": float(self._times[self.agreement_intervals - 1]),
            "min_abs_eigenvalue": float(np.min(np.abs(self.eigenvalues))) if len(self.eigenvalues) else 1.0,
        }

    def guarantee(self) -> str:
        t_c = self._times[self.agreement_intervals - 1]
        bound = (self.config.settling_time / (self.config.settling_time - t_c)) ** 3
        exact = (
            f"agreement after {self.agreement_intervals} intervals (t_c = {t_c:.3g} s), then one minimum-energy steer "
            f"over T_s - t_c (about E* x {bound:.3g}) plus signalling; "
            + (
                "exact (rounding / ε aside)"
                if self.config.u_max_choices is None
                else "exact only where every input stays within u_max (error set by rounding / ε there)"
            )
        )
        reads = rows_read(self.config, self.agreement_intervals + 1)  # from t_0 to the last update
        return lost_link_guarantee(self.config, exact, reads, self.LOST_LINK)


def _amplitude(value: Any) -> float:
    """ε as a float in :data:`AMPLITUDE_RANGE`, or an error naming ``amplitude`` and why the range ends there."""
    low, high = AMPLITUDE_RANGE
    return signal_amplitude(
        value,
        below=f"below {low:g} float64 rounding over ε takes the reads' digits (deadline error D(T_s)/D(0) a few "
        "1e-16 / ε: 9e-3 to 6e-2 at 1e-14, 1 to 6 at 1e-16 on a ring and a random digraph of 20 and paper_fig1) and "
        "saves no energy",
        above=f"above {high:g} the deadline error grows again like ε (rounding of the larger motions: 2e-9 to 6e-9 "
        "at 1e4, 0.1 to 0.7 at 1e12 on a ring and a random digraph of 20 and paper_fig1) while the energy grows like "
        "ε² (9e7 to 1.3e9 x E* at 1)",
    )


def _refuse_what_it_cannot_honour(config: Any, allow_limit: bool = False, allow_dropout: bool = False) -> None:
    name = "SignallingPolicy"
    if config.family is not None:
        raise ArgumentError(
            f"topology: {name} designs its weights offline for one known graph; a family draws a new graph per episode"
        )
    if config.switching != "periodic":
        raise ArgumentError(
            f"switching: {name} reads each neighbour on the instants the period gives it, not switching={config.switching!r}"
        )
    if config.u_max_choices is not None and not allow_limit:
        raise ArgumentError(
            f"u_max: {name} plans exact changes and cannot honour an input limit (allow_limit=True runs it "
            "anyway: exact wherever its inputs stay within the limit)"
        )
    refuse_unless_exact_raw_rows(config, name, allow_dropout, SignallingPolicy.LOST_LINK)
