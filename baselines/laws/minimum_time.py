"""A dead-beat law for a known fixed digraph: exact consensus in one interval per root of the minimal polynomial.

Law, source, proven graph class and refusals: docs: optimality.md, "Dead-beat on a known digraph (`minimum_time`)".
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from scipy.sparse import csgraph

from fxc_env.baselines.laws.motion_signals import plan_action
from fxc_env.baselines.laws.policy import LawPolicy, lost_link_guarantee, refuse_lost_links, rows_read
from fxc_env.config import config_of
from fxc_env.core.graphs import DENSE_LIMIT, Topology
from fxc_env.core.validation import ArgumentError, boolean


@dataclass(frozen=True)
class Factor:
    """One factor of the design: a real eigenvalue (one interval) or a complex pair (two intervals)."""

    eigenvalue: complex

    @property
    def intervals(self) -> int:
        return 2 if self.eigenvalue.imag != 0 else 1


#: Eigenvalues closer than this (relative to ``max(1, |mu|)``) are one eigenvalue of the design.
SAME_EIGENVALUE = 1e-9


def _same(a: complex, b: complex) -> bool:
    return abs(a - b) <= SAME_EIGENVALUE * max(1.0, abs(a))


def _block_index(block: np.ndarray, mu: complex, multiplicity: int) -> int:
    """The size of the largest Jordan block of ``mu`` in ``block`` (its index), by a rank test; at most ``multiplicity``.

    The smallest j with ``rank((block - mu I)^j) = size - multiplicity`` (singular values below ``1e-8`` of the
    largest are zero); ``multiplicity`` where the test is not conclusive.
    """
    size = len(block)
    shifted = block - (mu.real if mu.imag == 0 else mu) * np.eye(size)
    power, previous = np.eye(size, dtype=shifted.dtype), size
    for j in range(1, multiplicity):
        power = power @ shifted
        singular = np.linalg.svd(power, compute_uv=False)
        rank = int(np.sum(singular > 1e-8 * max(singular[0], 1e-300)))
        if rank == size - multiplicity:
            return j
        if rank >= previous:
            break
        previous = rank
    return multiplicity


def design_eigenvalues(topology: Topology) -> np.ndarray:
    """The roots of the minimal polynomial of ``Ŵ`` but 0, each repeated by its index (largest Jordan block).

    ``prod (I - Ŵ/mu)`` over these is zero on every disagreement mode. The index of ``mu`` is taken as the
    largest sum, along a chain of strongly connected components, of its index inside each
    (:func:`_block_index`), an upper bound (``Ŵ`` is block triangular over the components).

    Returns:
        ``(F,)`` complex, conjugate pairs both listed; ``F <= N - 1``.
    """
    if topology.period != 1:
        raise ArgumentError("topology: the minimum-time design needs one fixed graph")
    w_hat = sp.csr_array(sp.diags_array(1.0 / (topology.in_degree[0] + 1.0)) @ topology.laplacian(0))
    forward = topology.adjacency(0).T  # forward[j, i] != 0: edge j -> i
    n_comp, labels = csgraph.connected_components(forward, directed=True, connection="strong")
    coo = forward.tocoo()
    crossing = labels[coo.row] != labels[coo.col]
    condensed = sp.csr_array(
        (np.ones(int(crossing.sum())), (labels[coo.row[crossing]], labels[coo.col[crossing]])), shape=(n_comp, n_comp)
    )
    has_incoming = np.asarray(condensed.sum(axis=0)).ravel() > 0
    # Per component: its distinct eigenvalues with their index inside the component.
    per_component: list[list[tuple[complex, int]]] = []
    for comp in range(n_comp):
        members = np.flatnonzero(labels == comp)
        block = w_hat[members][:, members].toarray()
        values = np.linalg.eigvals(block) if len(members) > 1 else block.ravel().astype(complex)
        values = list(np.asarray(values, dtype=complex))
        if not has_incoming[comp]:
            values.pop(int(np.argmin(np.abs(values))))  # the consensus mode: simple, in the root component
        clusters: list[list[complex]] = []
        for mu in values:
            home = next((c for c in clusters if _same(c[0], mu)), None)
            home.append(mu) if home is not None else clusters.append([mu])
        per_component.append([(c[0], _block_index(block, c[0], len(c)) if len(c) > 1 else 1) for c in clusters])
    distinct: list[complex] = []
    for items in per_component:
        for mu, _ in items:
            if not any(_same(d, mu) for d in distinct):
                distinct.append(mu)
    # Components in topological order of the condensation, for the longest-chain sums.
    order = _topological_order(condensed, n_comp)
    predecessors = [condensed[:, [c]].nonzero()[0] for c in range(n_comp)]
    result = []
    for mu in distinct:
        own = np.array([sum(k for v, k in items if _same(v, mu)) for items in per_component])
        chain = np.zeros(n_comp, dtype=np.int64)
        for c in order:
            before = chain[predecessors[c]].max() if len(predecessors[c]) else 0
            chain[c] = own[c] + before
        result += [mu] * int(chain.max())
    return np.array(result, dtype=complex)


def _topological_order(condensed: sp.csr_array, n_comp: int) -> list[int]:
    indegree = np.asarray((condensed != 0).sum(axis=0)).ravel().astype(np.int64)
    ready = [c for c in range(n_comp) if indegree[c] == 0]
    order = []
    while ready:
        c = ready.pop()
        order.append(c)
        for d in condensed[[c], :].nonzero()[1]:
            indegree[d] -= 1
            if indegree[d] == 0:
                ready.append(int(d))
    return order


def leja_factors(eigenvalues: np.ndarray) -> list[Factor]:
    """One :class:`Factor` per real eigenvalue and per conjugate pair, in Leja order.

    Each next factor kills the eigenvalue where the partial product ``prod_j |1 - mu'/mu_j|`` is largest (ties:
    the larger modulus; Reichel 1990).
    """
    units = [complex(mu) for mu in np.asarray(eigenvalues, dtype=complex) if mu.imag >= 0]
    if not units:
        return []
    values = np.array(units)
    log_residual = np.zeros(len(values))
    remaining = np.ones(len(values), dtype=bool)
    order = []
    for _ in range(len(values)):
        candidates = np.flatnonzero(remaining)
        score = log_residual[candidates] + 1e-12 * np.abs(values[candidates])
        pick = candidates[np.argmax(score)]
        remaining[pick] = False
        order.append(pick)
        mu = values[pick]
        with np.errstate(divide="ignore"):
            log_residual += np.log(np.abs(1.0 - values / mu))
            if mu.imag != 0:
                log_residual += np.log(np.abs(1.0 - values / np.conj(mu)))
        log_residual = np.where(np.isneginf(log_residual), -1e300, log_residual)
    return [Factor(values[i]) for i in order]


def _log_factor(points: np.ndarray, factor: Factor) -> np.ndarray:
    """``log |1 - mu'/mu|`` (and of the conjugate for a pair) at ``points``, ``-inf`` where a mode dies."""
    mu = factor.eigenvalue
    with np.errstate(divide="ignore"):
        value = np.log(np.abs(1.0 - points / mu))
        if mu.imag != 0:
            value = value + np.log(np.abs(1.0 - points / np.conj(mu)))
    return value


def budget_factors(eigenvalues: np.ndarray, n_intervals: int) -> tuple[list[Factor], float]:
    """The factors to play in K intervals, and the modal residual they leave as the design sees it.

    When every factor fits, all of them (:func:`leja_factors`; residual 0). Otherwise the best, by the
    Jordan-aware modal score ``prod |1 - mu'/mu_j|`` (zero once ``mu'``'s own factor has been played its index
    times), of: the first factors in Leja order, or the factors of the s slowest modes for the best s
    (s = 0: the paper's plan alone), each followed by the paper's plan. The residual reported is
    :func:`design_residual`'s.
    """
    points = np.asarray(eigenvalues, dtype=complex)
    everything = leja_factors(points)
    if sum(f.intervals for f in everything) <= n_intervals:
        return everything, 0.0
    distinct, index = np.unique(points, return_counts=True)
    paper = Factor(1.0 + 0.0j)  # the paper's plan G_k = P_k: the factor of the eigenvalue 1

    def score(played: list[Factor], rest: int) -> float:
        log_q, own = np.zeros(len(distinct)), np.zeros(len(distinct))
        for factor in [*played, *([paper] * rest)]:
            value = _log_factor(distinct, factor)
            hit = np.isneginf(value)
            own += hit
            log_q += np.where(hit, 0.0, value)
        alive = own < index
        return float(np.max(log_q[alive])) if alive.any() else -np.inf

    def best_prefix(order: list[Factor]) -> tuple[float, int]:
        used, best = 0, (score([], n_intervals), 0)
        for s, factor in enumerate(order, start=1):
            if used + factor.intervals > n_intervals:
                break
            used += factor.intervals
            best = min(best, (score(order[:s], n_intervals - used), s))
        return best

    leja_score, leja_count = best_prefix(everything)
    slowest = sorted(everything, key=lambda f: abs(f.eigenvalue))
    slow_score, slow_count = best_prefix(slowest)
    if leja_score <= slow_score:
        return everything[:leja_count], float(np.exp(leja_score))
    chosen = leja_factors(np.array([f.eigenvalue for f in slowest[:slow_count]]))
    return chosen, float(np.exp(slow_score))


def design_residual(topology: Topology, factors: list[Factor], n_intervals: int) -> float:
    """The largest gain of the design's polynomial on a disagreement, from the matrix itself.

    ``max ||q(Ŵ) d|| / ||d||`` over the disagreements d (``xi^T d = 0``) for
    ``q(Ŵ) = prod_f (I - Ŵ/mu_f) (I - Ŵ)^(K - used)``, in float64; NaN above ``DENSE_LIMIT`` agents.
    """
    n = topology.n_agents
    if n > DENSE_LIMIT:
        return float("nan")
    if n == 1:
        return 0.0
    w_hat = sp.csr_array(sp.diags_array(1.0 / (topology.in_degree[0] + 1.0)) @ topology.laplacian(0))
    basis = scipy.linalg.null_space(topology.consensus_weights()[None, :])  # (N, N - 1)
    used = 0
    for factor in factors:
        if used + factor.intervals > n_intervals:
            break
        mu = factor.eigenvalue
        if factor.intervals == 1:
            basis = basis - (w_hat @ basis) / mu.real
        else:
            once = w_hat @ basis
            basis = basis - (2.0 * mu.real / abs(mu) ** 2) * once + (w_hat @ once) / abs(mu) ** 2
        used += factor.intervals
    for _ in range(n_intervals - used):
        basis = basis - w_hat @ basis
    return float(np.linalg.norm(basis, 2)) if np.all(np.isfinite(basis)) else float("inf")


def gain_schedule(factors: list[Factor], intervals: np.ndarray) -> tuple[np.ndarray, int]:
    """The gains ``G_k`` ``(K, 2, 2)`` (physical units: ``[[1, s], [1/s, 1]]``) and the intervals the factors use.

    Factors are played in order while they fit in the K intervals; the remaining intervals play the
    paper's plan ``G_k = P_k`` (the factor of the eigenvalue 1).
    """
    K = len(intervals)
    coasting = np.zeros((K, 2, 2))
    coasting[:, 0, 0] = coasting[:, 1, 1] = 1.0
    coasting[:, 0, 1] = intervals
    gains = coasting.copy()  # the paper's plan after the factors
    k = 0
    for factor in factors:
        if k + factor.intervals > K:
            break
        mu = factor.eigenvalue
        if factor.intervals == 1:
            gains[k] = coasting[k] / mu.real
        else:
            a, b = mu.real / abs(mu) ** 2, mu.imag / abs(mu) ** 2
            tau = intervals[k + 1]
            rotation = np.array([[a, -b * tau], [b / tau, a]])  # S R S^{-1}, S = diag(1, 1/tau)
            rotation_t = np.array([[a, b * tau], [-b / tau, a]])  # S R^T S^{-1}
            gains[k] = rotation @ coasting[k]
            gains[k + 1] = coasting[k + 1] @ rotation_t
        k += factor.intervals
    return gains, k


class MinimumTimePolicy(LawPolicy):
    """The minimum-time law on the local observation, every ``action_mode`` and ``obs_mode``.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` on a fixed digraph with ideal
            double-integrator agents (any schedule, ``dim``, modes, formation offsets).
        allow_noise: run under ``obs_noise`` too (off by default: the design assumes exact rows); the deadline
            error grows linearly with sigma (docs: optimality.md, "How far from optimal").
        allow_dropout: run under ``link_dropout`` too (off by default: :attr:`LOST_LINK` says what a lost link
            costs; docs: optimality.md, "Lost links").

    Raises:
        ArgumentError naming ``topology``, ``u_max``, ``obs_noise``, ``link_dropout``,
        ``switching`` or ``agent_model`` for what the design cannot honour.
    """

    NAME: ClassVar[str] = "minimum_time"
    LAW: ClassVar[str] = (
        "plan z_i(t_k+1) = P_k z_i + G_k r_i, G_k = P_k/μ (real μ) or R P_k, P_k Rᵀ (complex pair) per root μ "
        "of the minimal polynomial of (D+I)⁻¹L (repeated by its Jordan index) in Leja order, then the paper's plan"
    )
    SOURCE: ClassVar[str] = "this project (minimal-polynomial deadbeat design on the paper's sampled-data plan)"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed digraph with a directed spanning tree, ideal agents: exact after one interval per nonzero root of "
        "the minimal polynomial (minimum-time where that equals the radius)"
    )

    #: What one lost link costs the law (the refusal of ``link_dropout`` and :meth:`guarantee` say it).
    LOST_LINK: ClassVar[str] = (
        "a lost row leaves the mode its interval's factor removes, which the paper's plan then shrinks only as "
        "fast as the graph mixes: worst D(T_s)/D(0) of 20 seeds on a ring of 20, 0.13 at p = 1e-4, 10 at 1e-2; "
        "nothing left by T_s on the fast-mixing random digraph of 20 even at p = 0.1"
    )

    def __init__(self, env: Any, allow_noise: bool = False, allow_dropout: bool = False) -> None:
        config = config_of(env, type(self).__name__)
        boolean("allow_noise", allow_noise)
        refuse_what_a_graph_design_cannot_honour(
            config, type(self).__name__, allow_noise=allow_noise, allow_dropout=allow_dropout, lost_link=self.LOST_LINK
        )
        self.config = config
        self.layout = config.layout
        intervals = np.asarray(config.schedule.intervals, dtype=np.float64)
        eigenvalues = design_eigenvalues(config.topology)
        #: The needed intervals: one per real root of the minimal polynomial, two per complex pair, each
        #: repeated by its index (a tree's depth, a ring's N - 1).
        self.needed_intervals = int(np.sum(eigenvalues.imag >= 0) + np.sum(eigenvalues.imag > 0))
        #: The factors played, and the residual they leave: 0 when all fit in K (exact arithmetic);
        #: otherwise the largest gain on a disagreement of the played polynomial (:func:`design_residual`).
        self.factors, _ = budget_factors(eigenvalues, config.n_intervals)
        self.predicted_residual = 0.0
        if sum(f.intervals for f in self.factors) < self.needed_intervals:
            self.predicted_residual = design_residual(config.topology, self.factors, config.n_intervals)
            warnings.warn(
                f"n_intervals: K = {config.n_intervals} is below the {self.needed_intervals} intervals "
                f"{type(self).__name__} needs for exact consensus on this graph; it plays {len(self.factors)} "
                f"factors, then the paper's plan, and leaves a predicted residual {self.predicted_residual:.3g} "
                "(largest gain on a disagreement)",
                UserWarning,
                stacklevel=2,
            )
        #: ``(K, 2, 2)`` gains in physical units, and the intervals the factors use.
        self.gains, self.factor_intervals = gain_schedule(self.factors, intervals)
        # Normalized rows are (x_j - x_i)/s and T (v_j - v_i)/s; plans alpha_x = a_x/s, alpha_v = T a_v/s:
        # the gain in those units is S G S^{-1} with S = diag(1, T).
        scaled = self.gains.copy()
        scaled[:, 0, 1] /= intervals
        scaled[:, 1, 0] *= intervals
        self._table = scaled if config.obs_mode == "normalized" else self.gains
        self._intervals = intervals

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Plans (``plan`` mode) or end inputs (``accel``) from flat observations ``(..., obs_size)``."""
        c = self.config
        rows, mask, clock = self.layout.split(obs)
        real = mask[..., None, None]
        sums = np.sum(real * rows, axis=-3)  # (..., 2, dim): sum_j (x_j - x_i), sum_j (v_j - v_i)
        r = sums / (np.sum(mask, axis=-1)[..., None, None] + 1.0)
        k = np.clip(np.rint(clock[..., 2] * c.n_intervals).astype(np.int64), 0, c.n_intervals - 1)
        interval = 1.0 if c.obs_mode == "normalized" else self._intervals[k][..., None]
        return plan_action(self._table[k] @ r, c, interval)  # the plan (..., 2, dim): a_x, a_v (or normalized)

    def parameters(self) -> dict[str, float]:
        """The design: factors, the intervals they need and use, and the largest modulus of a gain."""
        magnitudes = np.abs([f.eigenvalue for f in self.factors]) if self.factors else np.ones(1)
        return {
            "factors": float(len(self.factors)),
            "needed_intervals": float(self.needed_intervals),
            "factor_intervals": float(self.factor_intervals),
            "min_abs_eigenvalue": float(magnitudes.min()),
            "predicted_residual": self.predicted_residual,
        }

    def guarantee(self) -> str:
        if self.factor_intervals < self.needed_intervals:
            return f"no exact guarantee: K = {self.config.n_intervals} < {self.needed_intervals} intervals the factors need"
        exact = f"exact in exact arithmetic after {self.needed_intervals} intervals (round-off aside)"
        reads = rows_read(self.config, self.needed_intervals)  # its factors' rows; consensus holds after
        return lost_link_guarantee(self.config, exact, reads, self.LOST_LINK)


def refuse_what_a_graph_design_cannot_honour(
    config: Any,
    name: str,
    periods: bool = False,
    allow_noise: bool = False,
    allow_dropout: bool = False,
    lost_link: str = "",
) -> None:
    """Raise :class:`ArgumentError` naming what a law designed offline for one known graph cannot honour.

    Families (a graph drawn per episode), random switching, a switching period (unless ``periods``),
    ``u_max``, ``obs_noise`` (unless ``allow_noise``), ``link_dropout`` (unless ``allow_dropout``; ``lost_link`` says what a lost
    link costs the law), agent models other than the double
    integrator, ``action_mode="residual"`` (the law emits whole plans or inputs, not corrections) and
    ``"plan_balanced"`` (its plans are in ``plan``'s units).
    """
    if config.action_mode in ("residual", "plan_balanced"):
        what = "'residual' corrections" if config.action_mode == "residual" else "'plan_balanced' units"
        raise ArgumentError(f"action_mode: {name} emits whole plans or inputs ('plan' or 'accel'), not {what}")
    if config.family is not None:
        raise ArgumentError(
            f"topology: {name} designs its gains offline for one known graph; a family draws a new graph per episode"
        )
    if config.topology.period != 1 and not periods:
        raise ArgumentError(
            f"topology: {name} designs its gains for one fixed graph; got a switching period of "
            f"{config.topology.period} graphs"
        )
    if config.switching != "periodic":
        raise ArgumentError(
            f"switching: {name} needs the graph it was designed for, not switching={config.switching!r}"
        )
    if config.u_max_choices is not None:
        raise ArgumentError(f"u_max: {name} plans exact changes and cannot honour an input limit")
    if config.obs_noise != 0 and not allow_noise:
        raise ArgumentError(
            f"obs_noise: {name} needs exact relative measurements; got obs_noise={config.obs_noise!r} "
            "(allow_noise=True runs it anyway: its error then grows linearly with the noise)"
        )
    refuse_lost_links(config, name, allow_dropout, lost_link or "its design assumes every row arrives")
    if config.model is not None:
        raise ArgumentError(
            f"agent_model: {name} is designed for the double integrator; got agent_model={config.agent_model!r}"
        )
