"""Numbers carried by small motions: what every law that signals through its motion shares
(:mod:`fxc_env.baselines.laws.signalling`, :mod:`fxc_env.baselines.laws.graph_agnostic`).

Arrays end in ``(2, dim)``: position and velocity parts. The derivation is
:mod:`fxc_env.baselines.laws.signalling`'s docstring (steps 1 to 4).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from fxc_env.baselines.laws.policy import LawPolicy, refuse_lost_links
from fxc_env.core import validation
from fxc_env.core.dynamics import input_from_plan
from fxc_env.core.graphs import Topology
from fxc_env.core.optimality import root_set
from fxc_env.core.validation import ArgumentError


def initial_offset(row: np.ndarray, t: float) -> np.ndarray:
    """``z_j(0) - z_i(0)`` ``(..., 2, dim)`` from a row measured at ``t`` before anyone deviated from coasting."""
    return np.stack([row[..., 0, :] - t * row[..., 1, :], row[..., 1, :]], axis=-2)


def read_deviation(row: np.ndarray, base: np.ndarray, own: np.ndarray, t: float) -> np.ndarray:
    """The neighbour's deviation from coasting ``d_j(t)`` ``(..., 2, dim)``: its row at ``t`` less the coasted
    initial offset ``Φ(t) base``, plus the reader's own deviation ``own`` (which the row subtracts)."""
    dev_x = row[..., 0, :] - (base[..., 0, :] + t * base[..., 1, :]) + own[..., 0, :]
    dev_v = row[..., 1, :] - base[..., 1, :] + own[..., 1, :]
    return np.stack([dev_x, dev_v], axis=-2)


def register_of(deviation: np.ndarray, amplitude: float, settling_time: float) -> np.ndarray:
    """The complex register ``(..., dim)`` a deviation ``ε (Re c, Im c / T_s)`` carries."""
    return deviation[..., 0, :] / amplitude + 1j * (settling_time * deviation[..., 1, :] / amplitude)


def deviation_of(register: np.ndarray, amplitude: float, settling_time: float) -> np.ndarray:
    """The deviation ``ε (Re c, Im c / T_s)`` ``(..., 2, dim)`` that carries a complex register (inverse of
    :func:`register_of`; with ``ε = 1`` the deviation at ``T_s`` that moves ``p_i`` by ``c``)."""
    return np.stack([amplitude * register.real, amplitude * register.imag / settling_time], axis=-2)


def predicted_register(base: np.ndarray, settling_time: float) -> np.ndarray:
    """``q_j(0) - q_i(0)`` ``(..., dim)`` from ``z_j(0) - z_i(0)``: the free-motion prediction's difference
    ``(x + T_s v, v)`` as a register ``p_x + i T_s p_v``."""
    velocity = settling_time * base[..., 1, :]
    return base[..., 0, :] + velocity + 1j * velocity


def signal_plan(target: np.ndarray, d: np.ndarray, interval: float) -> np.ndarray:
    """The plan ``(a_x, a_v)`` ``(..., 2, dim)`` that sets the deviation at the interval's end to ``target``."""
    return np.stack([target[..., 0, :] - d[..., 0, :] - interval * d[..., 1, :], target[..., 1, :] - d[..., 1, :]], -2)


def steer_plan(goal: np.ndarray, d: np.ndarray, t: float, interval: float, settling_time: float) -> np.ndarray:
    """The piece over ``[t, t + T]`` of the minimum-energy input (paper Remark 1) from deviation ``d`` at ``t``
    to deviation ``goal`` at ``T_s``, as a plan ``(..., 2, dim)``: the input ``λ_1 (H - s) + λ_2``,
    ``λ = G(H)^{-1} Δ``, ``H = T_s - t``, is affine on the interval, so the environment realises it exactly."""
    H, T = settling_time - t, interval
    need_x = goal[..., 0, :] - d[..., 0, :] - H * d[..., 1, :]
    need_v = goal[..., 1, :] - d[..., 1, :]
    lam1 = 12.0 * need_x / H**3 - 6.0 * need_v / H**2
    lam2 = -6.0 * need_x / H**2 + 4.0 * need_v / H
    a_x = lam1 * (H * T**2 / 2.0 - T**3 / 6.0) + lam2 * T**2 / 2.0
    a_v = lam1 * (H * T - T**2 / 2.0) + lam2 * T
    return np.stack([a_x, a_v], axis=-2)


def advance(d: np.ndarray, plan: np.ndarray, interval: float) -> np.ndarray:
    """The deviation at the interval's end: coasted ``P_k d`` plus the plan."""
    return np.stack([d[..., 0, :] + interval * d[..., 1, :] + plan[..., 0, :], d[..., 1, :] + plan[..., 1, :]], -2)


def current_instant(
    obs: np.ndarray, config: Any, law: str, next_instant: int, memory: tuple[int, ...] | None
) -> tuple[int, np.ndarray]:
    """The instant k of every agent's observation ``(..., N, obs_size)`` and its rows, checked against the memory.

    A law with memory is called with every agent's observation at once, one instant after the other from
    ``k = 0`` (which starts a new episode); ``memory`` is the lead shape ``(..., N)`` its memory holds (None:
    none yet). Raises ArgumentError naming ``observation`` otherwise.
    """
    layout = config.layout
    if obs.ndim < 2 or obs.shape[-2] != config.n_agents:
        raise ArgumentError(
            f"observation: {law} has memory and needs every agent's observation at once, "
            f"shape (..., {config.n_agents}, {layout.size}); got {obs.shape}"
        )
    rows, _, clock = layout.split(obs)
    ks = np.rint(clock[..., 2] * config.n_intervals).astype(np.int64)
    k = int(ks.reshape(-1)[0])
    if np.any(ks != k):
        raise ArgumentError("observation: every agent and episode of one call must be at the same instant")
    if k != 0 and (memory is None or k != next_instant or memory != obs.shape[:-1]):
        raise ArgumentError(
            f"observation: instant k = {k}, but the law's memory expects k = {next_instant} of the "
            "same batch (call it from k = 0, one instant after the other)"
        )
    return k, rows


def plan_action(plan: np.ndarray, config: Any, interval: float) -> np.ndarray:
    """The action ``(..., 2 dim)`` of a plan ``(..., 2, dim)``: the plan itself, or its end inputs in ``accel`` mode."""
    plan_x, plan_v = plan[..., 0, :], plan[..., 1, :]
    if config.action_mode == "plan":
        return np.concatenate([plan_x, plan_v], axis=-1)
    return np.concatenate(input_from_plan(plan_x, plan_v, interval), axis=-1)


class SignalPolicy(LawPolicy):
    """A law with memory (its own first measurements and plans): called with every agent's observation at once,
    the parallel env's dict or ``(..., N, obs_size)`` in agent order, one instant after the other from ``k = 0``
    (which starts an episode; :meth:`reset` forgets the episodes under way).

    Subclasses set :attr:`TITLE`, call ``super().__init__(config)`` once they have checked the
    configuration, and implement ``_reset`` (which sets ``_memory``, holding the own deviation ``"d"``
    ``(..., N, 2, dim)``) and ``_plan``.
    """

    #: How messages name the law (``"the signalling law"``).
    TITLE: ClassVar[str] = ""
    #: Its memory is per agent: one agent's observation alone is refused (:mod:`fxc_env.policies.protocol`).
    needs_team: ClassVar[bool] = True

    def __init__(self, config: Any) -> None:
        """Hold ``config``, its observation layout and sampling instants, and no episode yet."""
        self.config = config
        self.layout = config.layout
        self._times = np.asarray(config.schedule.times, dtype=np.float64)
        self._intervals = np.asarray(config.schedule.intervals, dtype=np.float64)
        self._memory: dict[str, np.ndarray] | None = None
        self._next_instant = 0

    def act(self, obs: np.ndarray) -> np.ndarray:
        """One instant of the law for every agent: plans (``plan`` mode) or end inputs (``accel``)."""
        obs = np.asarray(obs, dtype=np.float64)
        memory = None if self._memory is None else self._memory["d"].shape[:-2]
        k, rows = current_instant(obs, self.config, self.TITLE, self._next_instant, memory)
        if k == 0:
            self._reset(rows, obs.shape[:-1])
        plan = self._plan(k, rows, obs)
        self._next_instant = k + 1
        return plan_action(plan, self.config, self._intervals[k])

    def reset(self) -> None:
        """Forget the episodes under way (the next call must be at ``k = 0``, which also starts a new memory)."""
        self._memory = None
        self._next_instant = 0

    def _reset(self, rows: np.ndarray, lead: tuple[int, ...]) -> None:
        """A new episode's memory for the lead shape ``(..., N)``, from the rows at ``t_0``."""
        raise NotImplementedError

    def _plan(self, k: int, rows: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """The plan ``(a_x, a_v)`` ``(..., N, 2, dim)`` of every agent at instant k; updates the memory."""
        raise NotImplementedError


def averaging_weights(topology: Topology) -> np.ndarray:
    """``ξ`` ``(N,)``: the left null vector of ``Ŵ = (D + I)^{-1} L`` on the (union) graph, ``Σ ξ = 1``.

    Positive on the root set (:func:`fxc_env.core.optimality.root_set`), zero elsewhere (paper Theorem 1's weights).

    Raises:
        ArgumentError naming ``topology`` when the (union) graph has no directed spanning tree.
    """
    union = union_graph(topology)  # [i, j] = 1: i receives from j in some graph of the period
    roots = root_set(topology)
    degree = np.asarray(union.sum(axis=1)).ravel()
    w_hat = ((sp.diags_array(degree) - union).toarray() / (degree + 1.0)[:, None])[np.ix_(roots, roots)]
    # xi^T W-hat_RR = 0 with sum(xi) = 1: least squares on [W_RR^T; 1^T] xi = [0; 1] (exact: rank R - 1).
    system = np.vstack([w_hat.T, np.ones((1, len(roots)))])
    rhs = np.zeros(len(roots) + 1)
    rhs[-1] = 1.0
    xi = np.zeros(topology.n_agents)
    xi[roots] = np.linalg.lstsq(system, rhs, rcond=None)[0]
    return xi


def register_eigenvalues(topology: Topology) -> np.ndarray:
    """The ``N - 1`` nonzero eigenvalues of ``Ŵ = (D + I)^{-1} L`` on the (union) graph, complex.

    Block by block over the strongly connected components, so eigenvalues repeated across components come out
    exactly repeated.
    """
    union = union_graph(topology)
    degree = np.asarray(union.sum(axis=1)).ravel()
    w_hat = (sp.diags_array(degree) - union).toarray() / (degree + 1.0)[:, None]
    _, labels = csgraph.connected_components(union.T, directed=True, connection="strong")
    roots = root_set(topology)
    values = []
    for comp in np.unique(labels):
        members = np.flatnonzero(labels == comp)
        block = np.linalg.eigvals(w_hat[np.ix_(members, members)])
        if labels[roots[0]] == comp:
            block = np.delete(block, np.argmin(np.abs(block)))
        values.append(block)
    return np.concatenate(values)


def leja_order(eigenvalues: np.ndarray) -> np.ndarray:
    """The eigenvalues ``(N - 1,)`` in Leja order: each next one where ``|Π (1 - μ'/μ_k)|`` is largest so far."""
    points = np.asarray(eigenvalues, dtype=complex)
    remaining = list(range(len(points)))
    log_q = np.zeros(len(points))
    order = []
    while remaining:
        pick = max(remaining, key=lambda i: (log_q[i], abs(points[i])))
        order.append(points[pick])
        remaining.remove(pick)
        with np.errstate(divide="ignore"):
            log_q = log_q + np.log(np.abs(1.0 - points / points[pick]))
    return np.array(order, dtype=complex)


def cycling_outside_roots(topology: Topology) -> np.ndarray:
    """The agents outside the root set that lie on a cycle of the (union) graph, sorted ``(M,)``.

    None where the graph is strongly connected, or where its agents outside the root set form no cycle (trees,
    paths, stars). Where some do, the virtual iteration ``w <- D^-1 A w`` has decaying modes of that cycle's leaky
    block, slow ones among them.
    """
    _, labels = csgraph.connected_components(union_graph(topology), directed=True, connection="strong")
    on_cycle = np.bincount(labels)[labels] > 1
    on_cycle[root_set(topology)] = False
    return np.flatnonzero(on_cycle)


def union_graph(topology: Topology) -> sp.csr_array:
    """0/1 adjacency of the union of the period's graphs, sparse ``(N, N)``."""
    union = sp.csr_array(topology.union())
    union.data = np.ones_like(union.data)
    union.eliminate_zeros()
    return union


#: The signalling amplitudes ε every law that reads numbers off motions accepts, ``(smallest, largest)``
#: (``signalling``, ``graph_agnostic``, ``bounded_steer``): a read is off by about 1e-16 |q| / ε, so below 1e-12
#: rounding takes its digits, and above 1 the energy grows like ε² while the error grows again like ε
#: (measured per law in its module's amplitude check; docs: bad-input.md, "Law parameters").
AMPLITUDE_RANGE = (1e-12, 1.0)


def signal_amplitude(value: Any, below: str, above: str) -> float:
    """ε as a float in :data:`AMPLITUDE_RANGE`, or an :class:`ArgumentError` naming ``amplitude``, the range and
    what the calling law measured past each end (``below``, ``above``)."""
    return validation.in_range("amplitude", value, *AMPLITUDE_RANGE, below=below, above=above)


def refuse_unless_exact_raw_rows(config: Any, name: str, allow_dropout: bool = False, lost_link: str = "") -> None:
    """Raise :class:`ArgumentError` naming what a law that reads numbers off motions cannot honour.

    Lost links (unless ``allow_dropout``; ``lost_link`` says what one costs the law), rows rounded to a quantum
    (a signal far below it reads as 0), agent models other than the double integrator, observations other than
    raw (the coasting prediction is subtracted from physical rows) and actions other than plan/accel.
    """
    if config.obs_resolution != 0:
        raise ArgumentError(
            f"obs_resolution: {name} reads numbers off motions far below any quantum of the rows; "
            f"got obs_resolution={config.obs_resolution!r}"
        )
    refuse_lost_links(config, name, allow_dropout, lost_link or "it reads numbers from every link")
    if config.model is not None:
        raise ArgumentError(
            f"agent_model: {name} is designed for the double integrator; got agent_model={config.agent_model!r}"
        )
    if config.obs_mode != "raw":
        raise ArgumentError(
            f"obs_mode: {name} subtracts the coasting prediction from physical rows and needs obs_mode='raw', "
            f"got {config.obs_mode!r}"
        )
    if config.action_mode not in ("plan", "accel"):
        raise ArgumentError(f"action_mode: {name} supports 'plan' and 'accel', got {config.action_mode!r}")
