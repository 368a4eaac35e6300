"""Floors under measurement noise and input limits: what no controller, centralised or not, can beat.

Three settings of the environment change what is reachable at ``T_s``: measurement noise
(:func:`noise_floor`, linear in ``sigma``, the mean over :data:`NOISE_DRAWS` fixed draws), an
input limit (:func:`input_floor`, :func:`input_floor_bounds`, a linear programme over
:data:`INPUT_FACETS` facets) and a measurement quantum (:func:`resolution_floor`,
:func:`resolution_floor_bounds`, linear in the quantum, small linear programmes); each floor holds
for every law (the resolution floor: for every law that applies no input while it reads only
zeros, which every policy does under ``obs_mode="normalized"``; docs: optimality.md, "The floors,
derived").

Pure numpy/scipy: no environment, no torch.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, QhullError

from fxc_env.core import validation
from fxc_env.core.graphs import Topology
from fxc_env.core.metrics import spread
from fxc_env.core.validation import ArgumentError

__all__ = [
    "INPUT_FACETS",
    "NOISE_DRAWS",
    "NOISE_LIMIT",
    "input_floor",
    "input_floor_bounds",
    "noise_floor",
    "resolution_floor",
    "resolution_floor_bounds",
    "resolution_worst_state",
]

#: Draws of the least-squares error whose mean disagreement is the noise floor (fixed generator, seed 0).
NOISE_DRAWS = 4096
#: Largest N for which :func:`noise_floor` is computed (dense ``2N x 2N`` information matrix).
NOISE_LIMIT = 200
#: Switching instants ``tau = j T / m`` of the polygons of :func:`input_floor_bounds` (m).
INPUT_FACETS = 1024


def _information(topology: Topology, times: np.ndarray) -> np.ndarray:
    """``J = sum_k L_{k mod period} (x) Phi_k^T Phi_k``, ``(2N, 2N)``, state order ``(agent, [x, v])``."""
    n, period = topology.n_agents, topology.period
    information = np.zeros((2 * n, 2 * n))
    for g in range(period):
        t = times[g::period]
        gram = np.array([[len(t), t.sum()], [t.sum(), (t * t).sum() + len(t)]])  # sum_k Phi_k^T Phi_k
        edges = topology.edges[g]
        incidence = sp.csr_array(
            (
                np.r_[np.ones(len(edges)), -np.ones(len(edges))],
                (np.r_[edges[:, 0], edges[:, 1]], np.r_[0 : len(edges), 0 : len(edges)]),
            ),
            shape=(n, len(edges)),
        )
        information += np.kron((incidence @ incidence.T).toarray(), gram)
    return information


def noise_floor(topology: Topology, times: Any, sigma: Any, dim: int = 1) -> float:
    """The least expected ``D(T_s)`` (metres) any controller leaves under measurement noise ``sigma``.

    Args:
        topology: the graph (or switching period) the agents measure on; interval k uses
            graph ``k mod period``.
        times: the sampling instants ``t_0 .. t_K`` (seconds, ``times[-1] = T_s``), e.g.
            ``config.schedule.times``; rows are measured at ``t_0 .. t_{K-1}``.
        sigma: ``obs_noise``, the standard deviation of each measured component (m, m/s), >= 0.
        dim: the space dimension (noise is independent per axis).

    Returns:
        ``E[D(T_s)]`` of the least-squares error (docs: optimality.md, "The floors, derived"), in metres; divide by ``D(0)``
        for the relative floor. 0 for ``sigma = 0`` or a single agent; ``inf`` where the pooled
        rows cannot determine the disagreement (a graph without a spanning tree, or too few
        instants); NaN above :data:`NOISE_LIMIT` agents, where it is not computed.
    """
    instants = _checked_instants(topology, times)
    sigma = validation.real("sigma", sigma, 0.0)
    dim = validation.integer("dim", dim, 1)
    n = topology.n_agents
    if n == 1 or sigma == 0:
        return 0.0
    if n > NOISE_LIMIT:
        return float("nan")
    settling_time = float(instants[-1])
    # Coordinates of the disagreement: an orthonormal basis of the vectors with zero mean, per state.
    basis = np.linalg.svd(np.eye(n) - 1.0 / n)[0][:, : n - 1]
    reduce = np.kron(basis, np.eye(2))  # (2N, 2N - 2)
    information = reduce.T @ _information(topology, instants[:-1]) @ reduce
    eigenvalues, vectors = np.linalg.eigh(information)
    if eigenvalues[0] <= 1e-12 * max(eigenvalues[-1], 1.0):
        return float("inf")
    root = reduce @ (vectors / np.sqrt(eigenvalues))  # error = root @ g, g standard normal
    draws = np.random.default_rng(0).standard_normal((NOISE_DRAWS, dim, 2 * n - 2))
    error = (draws @ root.T).reshape(NOISE_DRAWS, dim, n, 2).transpose(0, 2, 1, 3)  # (S, N, dim, [x, v])
    positions = error[..., 0] + settling_time * error[..., 1]
    disagreement = spread(positions) + settling_time * spread(error[..., 1])
    return float(sigma * disagreement.mean())


def _polygons(settling_time: float, facets: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Outer and inner polygons of ``R`` (U = 1) as ``normals (F, 2)``, ``offsets (F,)``: ``normal . (d, w) <= offset``."""
    t = settling_time
    tau = np.linspace(0.0, t, facets + 1)
    w = 2 * tau - t
    d = 2 * t * tau - tau * tau - t * t / 2
    # Upper boundary d = f(w), concave, f'(w) = dd/dtau / dw/dtau = (t - tau); the lower one is its mirror.
    slope = t - tau
    outer_upper = np.stack([np.ones_like(w), -slope], axis=1), d - slope * w  # d - f'(w) w' <= f(w) - f'(w) w
    chord = (d[1:] - d[:-1]) / (w[1:] - w[:-1])
    inner_upper = np.stack([np.ones_like(chord), -chord], axis=1), d[:-1] - chord * w[:-1]
    polygons = []
    for normals, offsets in (outer_upper, inner_upper):
        # The mirror (d, w) -> (-d, -w) bounds from below; |w| <= T closes both.
        box = np.array([[0.0, 1.0], [0.0, -1.0]])
        polygons.append(np.concatenate([normals, -normals, box]))
        polygons.append(np.concatenate([offsets, offsets, [t, t]]))
    return polygons[0], polygons[1], polygons[2], polygons[3]


def _least_limit(normals: np.ndarray, offsets: np.ndarray, p: np.ndarray, v: np.ndarray) -> float:
    """``min U`` with ``(x* - p_i, v* - v_i)`` in ``U {normal . y <= offset}`` for all i (variables x*, v*, U)."""
    # normal . (x* - p_i, v* - v_i) <= offset U  <=>  n_d x* + n_w v* - offset U <= n_d p_i + n_w v_i.
    f = len(offsets)
    rows = np.tile(np.stack([normals[:, 0], normals[:, 1], -offsets], axis=1), (len(p), 1))
    bounds = (normals[None, :, 0] * p[:, None] + normals[None, :, 1] * v[:, None]).ravel()
    scale = max(np.max(np.abs(p)), np.max(np.abs(v)), 1.0)
    result = linprog(
        c=[0.0, 0.0, 1.0],
        A_ub=rows,
        b_ub=bounds / scale,
        bounds=[(None, None), (None, None), (0.0, None)],
        method="highs",
    )
    if result.status != 0:
        raise ArithmeticError(f"input floor: the linear programme did not solve ({result.message}; {f} facets)")
    return float(result.x[2] * scale)


def _hull(p: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of the convex hull of the points ``(p_i, v_i)``: ``p_i in y - U R`` for all i iff for these (R is convex)."""
    try:
        vertices = ConvexHull(np.stack([p, v], axis=1)).vertices
    except (QhullError, ValueError):  # fewer than 3 points, or all on a line: keep them all
        return p, v
    return p[vertices], v[vertices]


def input_floor_bounds(x0: Any, v0: Any, settling_time: Any, facets: int = INPUT_FACETS) -> tuple[float, float]:
    """``(lower, upper)`` on the least input limit ``u_max`` (m/s², per component) of exact consensus at ``T_s``.

    ``lower``: the linear programme on the polygon enclosing the reachable set (no controller,
    centralised or not, reaches exact consensus with a smaller ``u_max``); ``upper``: on the polygon
    inside it, reached by bang-bang inputs switching once at a multiple of ``T_s / facets``. The
    largest over the ``dim`` axes (the limit clips each component).

    Args:
        x0, v0: initial positions and velocities ``(N, dim)`` (or ``(N,)``), in m and m/s.
        settling_time: ``T_s`` in seconds, > 0.
        facets: switching instants per polygon side (>= 2).
    """
    x = validation.real_array("x0", x0, "initial positions (N, dim)")
    v = validation.real_array("v0", v0, "initial velocities (N, dim)")
    if x.ndim == 1:
        x, v = x[:, None], v.reshape(-1, 1) if v.ndim == 1 else v
    if x.ndim != 2 or v.shape != x.shape:
        raise ArgumentError(f"x0, v0: expected two arrays (N, dim) of one shape, got {x.shape} and {v.shape}")
    validation.finite_array("x0, v0", np.stack([x, v]))
    t = validation.real("settling_time", settling_time, positive=True)
    facets = validation.integer("facets", facets, 2)
    outer_normals, outer_offsets, inner_normals, inner_offsets = _polygons(t, facets)
    lower = upper = 0.0
    for axis in range(x.shape[1]):
        p, w = _hull(x[:, axis] + t * v[:, axis], v[:, axis])
        if np.ptp(p) == 0 and np.ptp(w) == 0:
            continue
        lower = max(lower, _least_limit(outer_normals, outer_offsets, p, w))
        upper = max(upper, _least_limit(inner_normals, inner_offsets, p, w))
    return lower, upper


def input_floor(x0: Any, v0: Any, settling_time: Any) -> float:
    """The least ``u_max`` (m/s²) for which any controller reaches exact consensus at ``T_s`` (the lower bound of :func:`input_floor_bounds`)."""
    return input_floor_bounds(x0, v0, settling_time)[0]


def _silent_rows(topology: Topology, instants: np.ndarray) -> np.ndarray:
    """The rows ``a`` of ``|a . z| <= 1/2`` that keep every reading 0 under free motion, ``(M, 2N)``, ``z = (x, v)``.

    Per measured edge ``(j, i)`` of graph ``g``: the velocity row, and the position row at the
    first and the last instant ``t_k`` (``k = g mod period``) it is measured (``x_j - x_i + t (v_j - v_i)``
    is affine in ``t``, so bounded at both ends means bounded at every instant between).
    """
    n, period = topology.n_agents, topology.period
    rows = []
    for g in range(period):
        measured = instants[g::period]
        if len(measured) == 0:
            continue
        for j, i in topology.edges[g]:
            for t in dict.fromkeys((measured[0], measured[-1])):
                row = np.zeros(2 * n)
                row[[j, i, n + j, n + i]] = [1.0, -1.0, t, -t]
                rows.append(row)
            row = np.zeros(2 * n)
            row[[n + j, n + i]] = [1.0, -1.0]
            rows.append(row)
    return np.array(rows).reshape(-1, 2 * n)


def _free_disagreement(states: np.ndarray, settling_time: float) -> np.ndarray:
    """``D(T_s)`` of free motion from states ``(S, 2N)`` (1-D), ``(S,)``."""
    n = states.shape[-1] // 2
    x, v = states[..., :n], states[..., n:]
    return np.ptp(x + settling_time * v, axis=-1) + settling_time * np.ptp(v, axis=-1)


def _maximise(rows: np.ndarray, objective: np.ndarray) -> tuple[float, np.ndarray]:
    """``max objective . z`` over ``|rows @ z| <= 1/2`` with agent 0 at ``x = v = 0`` (the gauge); value and maximiser."""
    size = rows.shape[1]
    n = size // 2
    free = np.ones(size, dtype=bool)
    free[[0, n]] = False
    result = linprog(
        c=-objective[free],
        A_ub=np.concatenate([rows[:, free], -rows[:, free]]),
        b_ub=np.full(2 * len(rows), 0.5),
        bounds=[(None, None)] * int(free.sum()),
        method="highs",
    )
    if result.status != 0:
        raise ArithmeticError(f"resolution floor: the linear programme did not solve ({result.message})")
    state = np.zeros(size)
    state[free] = result.x
    return float(-result.fun), state


def _pair_objective(n: int, settling_time: float, high: tuple[int, int], low: tuple[int, int]) -> np.ndarray:
    """``x_a(T) - x_b(T) + T (v_c - v_d)`` as a vector over ``z = (x, v)``; ``high = (a, c)``, ``low = (b, d)``."""
    objective = np.zeros(2 * n)
    (a, c), (b, d) = high, low
    objective[[a, n + a]] += [1.0, settling_time]
    objective[[b, n + b]] -= [1.0, settling_time]
    objective[n + c] += settling_time
    objective[n + d] -= settling_time
    return objective


def _checked_instants(topology: Any, times: Any) -> np.ndarray:
    """``times`` checked as ``t_0 = 0 < ... < t_K`` (seconds), for a :class:`Topology`."""
    if not isinstance(topology, Topology):
        raise ArgumentError(f"topology: expected a fxc_env.core.graphs.Topology, got {type(topology).__name__}")
    instants = validation.real_array("times", times, "the sampling instants t_0 .. t_K (seconds)")
    if instants.ndim != 1 or len(instants) < 2 or not np.all(np.diff(instants) > 0) or instants[0] != 0:
        raise ArgumentError(f"times: expected increasing instants t_0 = 0 .. t_K = T_s, got shape {instants.shape}")
    return instants


def resolution_worst_state(topology: Topology, times: Any, refinements: int = 8) -> tuple[np.ndarray, float]:
    """An initial state no reading of which leaves 0 at quantum 1, and its free ``D(T_s)``: ``((2, N), float)``.

    The state (rows ``x``, ``v``; 1-D, agent 0 at rest at 0) keeps every relative row
    ``|x_j - x_i|``, ``|v_j - v_i|`` measured at ``t_0 .. t_{K-1}`` within 1/2 while it coasts, so
    with quantum ``q`` the state times ``q`` reads all zeros. Found by linear programmes over that
    polytope: each agent's ``x_i + 2 T_s v_i`` against agent 0's, then the extreme pairs of the best
    state found (``refinements`` rounds). Any state of the polytope gives a true floor; this one makes it large.
    """
    instants = _checked_instants(topology, times)
    n, settling_time = topology.n_agents, float(instants[-1])
    if n == 1:
        return np.zeros((2, 1)), 0.0
    rows = _silent_rows(topology, instants[:-1])
    best, best_value = np.zeros(2 * n), 0.0
    for i in range(1, n):
        state = _maximise(rows, _pair_objective(n, settling_time, (i, i), (0, 0)))[1]
        value = float(_free_disagreement(state, settling_time))
        if value > best_value:
            best, best_value = state, value
    for _ in range(refinements):
        final, velocity = best[:n] + settling_time * best[n:], best[n:]
        high, low = (int(np.argmax(final)), int(np.argmax(velocity))), (int(np.argmin(final)), int(np.argmin(velocity)))
        state = _maximise(rows, _pair_objective(n, settling_time, high, low))[1]
        value = float(_free_disagreement(state, settling_time))
        if value <= best_value * (1 + 1e-12):
            break
        best, best_value = state, value
    return best.reshape(2, n), best_value


def resolution_floor_bounds(topology: Topology, times: Any, dim: int = 1) -> tuple[float, float]:
    """``(lower, upper)`` on the worst free ``D(T_s)`` over the states that read all zeros, per metre of quantum.

    ``lower`` is :func:`resolution_worst_state`'s value; ``upper`` bounds every such state's
    ``e_x(T_s) + T_s e_v`` by the largest ``x_i(T_s) - x_j(T_s)`` plus ``T_s`` times the largest
    ``v_i - v_j`` over the polytope (a linear programme per pair; it is symmetric). Both times
    ``sqrt(dim)`` (the same state on every axis; and no axis does better). ``lower = upper``
    would mean the floor is the exact worst case of a law that applies no input on zero readings.
    """
    instants = _checked_instants(topology, times)
    dim = validation.integer("dim", dim, 1)
    n, settling_time = topology.n_agents, float(instants[-1])
    if n == 1:
        return 0.0, 0.0
    lower = resolution_worst_state(topology, instants)[1]
    rows = _silent_rows(topology, instants[:-1])
    positions, velocities = [], []
    for i in range(n):
        for j in range(i + 1, n):
            position, velocity = np.zeros(2 * n), np.zeros(2 * n)
            position[[i, j, n + i, n + j]] = [1.0, -1.0, settling_time, -settling_time]  # x_i(T) - x_j(T)
            velocity[[n + i, n + j]] = [1.0, -1.0]
            positions.append(_maximise(rows, position)[0])
            velocities.append(_maximise(rows, velocity)[0])
    upper = max(positions) + settling_time * max(velocities)
    return float(np.sqrt(dim) * lower), float(np.sqrt(dim) * upper)


def resolution_floor(topology: Topology, times: Any, quantum: Any, dim: int = 1) -> np.ndarray:
    """The worst ``D(T_s)`` (metres) of an initial state whose every reading is 0 at quantum ``q``: a floor per ``q``.

    With rows rounded to ``q`` (``obs_resolution``), the states ``q z`` with ``z`` in the polytope of
    :func:`resolution_worst_state` read all zeros at every instant, so a law that applies no input
    while it reads only zeros (every policy under ``obs_mode="normalized"``, where the environment
    multiplies each plan by the local scale, 0 then; every law of ``fxc_env.baselines``) lets
    them coast: no such law ends below this ``D(T_s)`` on all of them (docs: optimality.md,
    "The floors, derived"). A worst case over a set of initial states, not a bound on every episode.

    Args:
        topology: the graph (or switching period); interval k uses graph ``k mod period``.
        times: the sampling instants ``t_0 .. t_K`` (seconds, ``times[-1] = T_s``).
        quantum: ``obs_resolution`` (m, m/s), >= 0: a number or an array (e.g. one per episode).
        dim: the space dimension.

    Returns:
        ``sqrt(dim) c q`` in metres, of ``quantum``'s shape (``c``: :func:`resolution_worst_state`'s value).
    """
    quanta = validation.real_array("quantum", quantum, "obs_resolution values (m, m/s)")
    if not (np.all(np.isfinite(quanta)) and np.all(quanta >= 0)):
        raise ArgumentError(f"quantum: expected finite numbers >= 0, got {quantum!r}")
    dim = validation.integer("dim", dim, 1)
    return np.sqrt(dim) * resolution_worst_state(topology, times)[1] * quanta
