"""A minimum-time law for a known fixed digraph: exact consensus in one interval per eigenvalue.

Law (derived for this project; README, "How far from optimal"). Agent i reads its aggregated
relative row ``r_i = (1/(d_i+1)) sum_{j in N_i} (z_j - z_i)``, ``z = (x, v)``, at ``t_k`` and plans

    z_i(t_{k+1}) = P_k z_i(t_k) + G_k r_i(t_k),    P_k = [[1, T_k], [0, 1]]  (coasting),

which the minimum-energy input of paper Remark 1 realises exactly (the plan relative to coasting
is ``(a_x, a_v) = G_k r_i``). The 2 x 2 gain ``G_k`` is the same for every agent and chosen by the
clock from a schedule designed **offline** from the graph. With ``r = -Ŵ z``, ``Ŵ = (D + I)^{-1} L``,
interval k acts on the mode of an eigenvalue ``mu'`` of ``Ŵ`` as ``P_k - mu' G_k``:

- a real eigenvalue ``mu``: ``G_k = P_k / mu`` multiplies every mode by ``(1 - mu'/mu)``;
- a complex pair ``mu, conj(mu)``: with ``R = [[a, -b], [b, a]]``, ``a = Re mu/|mu|^2``,
  ``b = Im mu/|mu|^2``, two consecutive intervals ``G_k = R P_k`` and ``G_{k+1} = P_{k+1} R^T``
  give ``P_{k+1} (I - mu' R^T)(I - mu' R) P_k = (1 - mu'/mu)(1 - mu'/conj(mu)) P_{k+1} P_k``
  (``R + R^T = 2a I``, ``R^T R = I/|mu|^2``); here ``R`` is conjugated by ``diag(1, 1/T_{k+1})`` so
  that its entries carry the units of a gain;
- an eigenvalue of multiplicity s (a Jordan block: a path's eigenvalues are all 1/2) repeats its
  factor s times; ``mu = 0``, the consensus mode, is never touched.

After one factor per nonzero eigenvalue every disagreement mode is zero: a directed ring of N agrees
after N - 1 intervals, :func:`fxc_env.core.optimality.propagation_bound`. The factors run in Leja
order (each next one kills the mode whose partial product is largest), so partial products stay
small; afterwards the agents play the paper's plan (``G_k = P_k``, eq. 11), which holds consensus
and damps the round-off left. The consensus value is the paper's, ``xi^T z(0)`` coasted (Theorem 1:
every factor is a polynomial in ``Ŵ`` equal to 1 at 0). With fewer intervals K than factors, the
design plays the subset that leaves the smallest predicted residual (:func:`budget_factors`).

- Source: this project (a deadbeat / finite-time "minimal polynomial" design in the spirit of
  Sundaram & Hadjicostis 2007 and Kibangou 2012, on the sampled-data plan of the paper).
- Proven graph class: a fixed digraph with a directed spanning tree, ideal agents (exact in exact
  arithmetic after the factors; float64 round-off grows with the partial products, so large slow
  rings lose digits).
- It refuses what it cannot honour, by name: switching topologies and topology families (the design
  needs the one graph), ``u_max``, ``obs_noise`` (unless ``allow_noise=True``: the error then grows
  linearly with the noise, 2.2e-6 at sigma = 1e-6 on the ring of 20), ``link_dropout``,
  ``switching='random'`` and agent models other than the double integrator.

Its price is energy: the early factors of a slow graph move agents far (README figures).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from fxc_env.baselines.policy import describe_law
from fxc_env.config import config_of
from fxc_env.core.dynamics import input_from_plan
from fxc_env.core.graphs import Topology
from fxc_env.core.validation import ArgumentError


@dataclass(frozen=True)
class Factor:
    """One factor of the design: a real eigenvalue (one interval) or a complex pair (two intervals)."""

    eigenvalue: complex

    @property
    def intervals(self) -> int:
        return 2 if self.eigenvalue.imag != 0 else 1


def nonzero_eigenvalues(topology: Topology) -> np.ndarray:
    """The nonzero eigenvalues of ``Ŵ = (D + I)^{-1} L`` with algebraic multiplicity, ``(N - 1,)`` complex.

    Computed block by block over the strongly connected components (``Ŵ`` is block triangular in
    their order), so a repeated eigenvalue of separate components (a path's 1/2) comes out exactly
    repeated instead of split by a Jordan block's perturbation. The consensus eigenvalue 0, simple
    under a directed spanning tree, lies in the root component and is removed there.
    """
    if topology.period != 1:
        raise ArgumentError("topology: the minimum-time design needs one fixed graph")
    n = topology.n_agents
    identity_weight = 1.0 / (topology.in_degree[0] + 1.0)
    laplacian = topology.laplacian(0)
    w_hat = sp.csr_array(sp.diags_array(identity_weight) @ laplacian)
    forward = topology.adjacency(0).T  # forward[j, i] != 0: edge j -> i
    n_comp, labels = csgraph.connected_components(forward, directed=True, connection="strong")
    coo = forward.tocoo()
    crossing = labels[coo.row] != labels[coo.col]
    has_incoming = np.zeros(n_comp, dtype=bool)
    has_incoming[labels[coo.col[crossing]]] = True
    values = []
    for comp in range(n_comp):
        members = np.flatnonzero(labels == comp)
        block = w_hat[members][:, members].toarray()
        eigenvalues = np.linalg.eigvals(block) if len(members) > 1 else block.ravel().astype(complex)
        eigenvalues = np.asarray(eigenvalues, dtype=complex)
        if not has_incoming[comp]:
            eigenvalues = np.delete(eigenvalues, np.argmin(np.abs(eigenvalues)))  # the consensus mode
        values.append(eigenvalues)
    result = np.concatenate(values) if values else np.zeros(0, dtype=complex)
    assert len(result) == n - 1
    return result


def leja_factors(eigenvalues: np.ndarray) -> list[Factor]:
    """One :class:`Factor` per real eigenvalue and per conjugate pair, in Leja order.

    The first kills the eigenvalue of largest modulus; each next one the eigenvalue ``mu'`` where
    the partial product ``prod_j |1 - mu'/mu_j|`` of the factors so far is largest (ties: the larger
    modulus), the greedy ordering that keeps partial products small (Reichel 1990).
    """
    points = np.asarray(eigenvalues, dtype=complex)
    units = [complex(mu) for mu in points if mu.imag >= 0]
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
    """The factors to play in K intervals, and the largest modal residual they leave (predicted).

    When every factor fits, all of them (:func:`leja_factors`; residual 0). Otherwise the best, by the
    largest predicted ``|q(mu')|`` over the nonzero eigenvalues, of: the first factors in Leja order,
    or the factors of the s slowest modes (smallest ``|mu|``, played in Leja order) for the best s,
    each followed by the paper's plan (factor ``1 - mu'``) on the intervals left. The prediction is
    modal (exact for normal ``Ŵ``, a ring's); the paper's plan alone is the case s = 0.
    """
    points = np.asarray(eigenvalues, dtype=complex)
    everything = leja_factors(points)
    if sum(f.intervals for f in everything) <= n_intervals:
        return everything, 0.0
    with np.errstate(divide="ignore"):
        reference = np.log(np.abs(1.0 - points))  # the paper's plan on one interval

    def best_prefix(order: list[Factor]) -> tuple[float, int]:
        log_q, used = np.zeros(len(points)), 0
        best = (float(np.max(log_q + n_intervals * reference)), 0)
        for s, factor in enumerate(order, start=1):
            if used + factor.intervals > n_intervals:
                break
            log_q = log_q + _log_factor(points, factor)
            used += factor.intervals
            best = min(best, (float(np.max(log_q + (n_intervals - used) * reference)), s))
        return best

    leja_score, leja_count = best_prefix(everything)
    slowest = sorted(everything, key=lambda f: abs(f.eigenvalue))
    slow_score, slow_count = best_prefix(slowest)
    if leja_score <= slow_score:
        return everything[:leja_count], float(np.exp(leja_score))
    chosen = leja_factors(np.array([f.eigenvalue for f in slowest[:slow_count]]))
    return chosen, float(np.exp(slow_score))


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


class MinimumTimePolicy:
    """The minimum-time law on the local observation, every ``action_mode`` and ``obs_mode``.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` on a fixed digraph with ideal
            double-integrator agents (any schedule, ``dim``, modes, formation offsets).
        allow_noise: run under ``obs_noise`` too (off by default: the design assumes exact rows).
            The law is linear, so the noise passes through its gains and the deadline error grows
            linearly with sigma (README, "How far from optimal", measured on the ring of 20).

    Raises:
        ArgumentError naming ``topology``, ``u_max``, ``obs_noise``, ``link_dropout``,
        ``switching`` or ``agent_model`` for what the design cannot honour.
    """

    NAME: ClassVar[str] = "minimum_time"
    LAW: ClassVar[str] = (
        "plan z_i(t_k+1) = P_k z_i + G_k r_i, G_k = P_k/μ (real μ) or R P_k, P_k Rᵀ (complex pair) per eigenvalue "
        "μ of (D+I)⁻¹L in Leja order, then the paper's plan"
    )
    SOURCE: ClassVar[str] = "this project (minimal-polynomial deadbeat design on the paper's sampled-data plan)"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed digraph with a directed spanning tree, ideal agents: exact after one interval per nonzero eigenvalue"
    )

    def __init__(self, env: Any, allow_noise: bool = False) -> None:
        config = config_of(env, type(self).__name__)
        if not isinstance(allow_noise, bool):
            raise ArgumentError(f"allow_noise: expected True or False, got {allow_noise!r}")
        _refuse_what_it_cannot_honour(config, allow_noise)
        self.config = config
        self.layout = config.layout
        intervals = np.asarray(config.schedule.intervals, dtype=np.float64)
        eigenvalues = nonzero_eigenvalues(config.topology)
        #: The needed intervals: one per real eigenvalue, two per complex pair.
        self.needed_intervals = int(np.sum(eigenvalues.imag >= 0) + np.sum(eigenvalues.imag > 0))
        #: The factors played, and the largest modal residual they leave (0 when all fit in K).
        self.factors, self.predicted_residual = budget_factors(eigenvalues, config.n_intervals)
        #: ``(K, 2, 2)`` gains in physical units, and the intervals the factors use.
        self.gains, self.factor_intervals = gain_schedule(self.factors, intervals)
        # Normalized rows are (x_j - x_i)/s and T (v_j - v_i)/s; plans alpha_x = a_x/s, alpha_v = T a_v/s:
        # the gain in those units is S G S^{-1} with S = diag(1, T).
        scaled = self.gains.copy()
        scaled[:, 0, 1] /= intervals
        scaled[:, 1, 0] *= intervals
        self._table = scaled if config.obs_mode == "normalized" else self.gains
        self._intervals = intervals

    def __call__(self, observation: np.ndarray | Mapping[str, np.ndarray]) -> np.ndarray:
        """Action(s) ``(..., 2 dim)`` for observation(s) ``(..., obs_size)`` (flat or dict)."""
        return self.act(self.layout.flat(observation))

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Plans (``plan`` mode) or end inputs (``accel``) from flat observations ``(..., obs_size)``."""
        c = self.config
        rows, mask, clock = self.layout.split(obs)
        real = mask[..., None, None]
        sums = np.sum(real * rows, axis=-3)  # (..., 2, dim): sum_j (x_j - x_i), sum_j (v_j - v_i)
        r = sums / (np.sum(mask, axis=-1)[..., None, None] + 1.0)
        k = np.clip(np.rint(clock[..., 2] * c.n_intervals).astype(np.int64), 0, c.n_intervals - 1)
        plan = self._table[k] @ r  # (..., 2, dim): a_x, a_v (or their normalized alpha)
        plan_x, plan_v = plan[..., 0, :], plan[..., 1, :]
        if c.action_mode == "plan":
            return np.concatenate([plan_x, plan_v], axis=-1)
        interval = 1.0 if c.obs_mode == "normalized" else self._intervals[k][..., None]
        return np.concatenate(input_from_plan(plan_x, plan_v, interval), axis=-1)

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

    def describe(self) -> dict[str, str]:
        """Law, source, proven graph class and parameters, for tables and logs."""
        return describe_law(self)

    def guarantee(self) -> str:
        if self.factor_intervals < self.needed_intervals:
            return f"no exact guarantee: K = {self.config.n_intervals} < {self.needed_intervals} intervals the factors need"
        return f"exact in exact arithmetic after {self.needed_intervals} intervals (round-off aside)"


def _refuse_what_it_cannot_honour(config: Any, allow_noise: bool = False) -> None:
    name = "MinimumTimePolicy"
    if config.family is not None:
        raise ArgumentError(
            f"topology: {name} designs its gains offline for one known graph; a family draws a new graph per episode"
        )
    if config.topology.period != 1:
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
    if config.link_dropout != 0:
        raise ArgumentError(
            f"link_dropout: {name} needs every link of its graph; got link_dropout={config.link_dropout!r}"
        )
    if config.model is not None:
        raise ArgumentError(
            f"agent_model: {name} is designed for the double integrator; got agent_model={config.agent_model!r}"
        )
