"""How far from optimal: the minimum-energy bound, the intervals bounds and the settled interval.

The energy and radius bounds hold for *every* controller of the consensus task, centralised or not;
the all-roots bound for laws whose value depends on every root (paper Remark 1, Theorems 1-2; the
derivations: docs: optimality.md, "The bounds, derived"). :func:`settled_interval` reads, from a
run's relative disagreements ``D(t_k)/D(0)``, the interval after which the error stayed below a
tolerance.

Pure numpy/scipy: no environment, no torch.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from fxc_env.core import validation
from fxc_env.core.graphs import Topology
from fxc_env.core.linear import LinearModel
from fxc_env.core.validation import ArgumentError

__all__ = [
    "all_roots_bound",
    "energy_bound",
    "episode_energy_bound",
    "linear_energy_bound",
    "propagation_bound",
    "radius_bound",
    "radius_centre",
    "reach_intervals",
    "root_set",
    "settled_interval",
]


def _states(name: str, value: Any, minimum_ndim: int) -> np.ndarray:
    array = validation.real_array(name, value, f"an array of at least {minimum_ndim} dimensions")
    if array.ndim < minimum_ndim:
        raise ArgumentError(f"{name}: expected an array of at least {minimum_ndim} dimensions, got shape {array.shape}")
    return validation.finite_array(name, array)


def energy_bound(x0: Any, v0: Any, settling_time: Any) -> np.ndarray:
    """``E*`` in m²/s³: the least energy ``sum_i int |u_i|^2 dt`` of any exact consensus at ``T_s``.

    Double-integrator agents (paper eq. 1). ``E* = sum_i (p_i - p̄)^T G(T_s)^{-1} (p_i - p̄)`` with
    ``p_i = (x_i + T_s v_i, v_i)`` per axis (docs: optimality.md, "The bounds, derived"); reached by one affine input per agent
    that steers it to the mean of the free-motion predictions.

    Args:
        x0, v0: initial positions (m) and velocities (m/s), ``(..., N, dim)`` (batched over the
            leading dimensions; ``(N,)`` is one 1-D episode).
        settling_time: ``T_s`` in seconds, > 0.

    Returns:
        ``(...)`` float64: one bound per episode, summed over agents and axes; 0 for a team already in
        exact consensus at any ``T_s``.

    Raises:
        ArgumentError naming ``settling_time`` (and the episodes) where a disagreeing team's ``E*`` has no
        float64 value: above 1.8e308 (``T_s -> 0``, e.g. ``T_s = 1e-110`` on the paper's example) or below
        2.2e-308, float64's smallest normal number (offsets of 1e-170 m at ``T_s = 1`` s), where it would
        read as ``inf`` or as the 0 of a team in consensus (docs: bad-input.md, "Law parameters").

    The per-axis sum is evaluated as ``12 (s / √T_s)² + (w / √T_s)²``, ``s = a / T_s + w / 2``, with ``a`` and ``w``
    the position and velocity offsets from the team's means (``d = a + T_s w`` expanded: a sum of squares,
    with no cancellation and no power of ``T_s`` that can underflow or overflow on its own).
    """
    x = _states("x0", x0, 1)
    v = _states("v0", v0, 1)
    if x.shape != v.shape:
        raise ArgumentError(f"v0: expected the shape of x0 {x.shape}, got {v.shape}")
    T = validation.real("settling_time", settling_time, positive=True)
    bound, beyond = _double_integrator_bound(x, v, T)
    if np.any(beyond):
        raise ArgumentError(f"settling_time: {_beyond_text(bound, beyond)} at T_s = {T:g} s")
    return bound


def _double_integrator_bound(x: np.ndarray, v: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`energy_bound`'s value ``(...)`` and where it has none in float64 ``(...)`` bool (no checks)."""
    if x.ndim == 1:
        x, v = x[:, None], v[:, None]
    a = x - x.mean(axis=-2, keepdims=True)
    w = v - v.mean(axis=-2, keepdims=True)
    root = np.sqrt(T)
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        s = (a / T + w / 2.0) / root
        scaled_w = w / root
        bound = (12.0 * s * s + scaled_w * scaled_w).sum(axis=(-2, -1))
    disagreeing = np.any((a != 0) | (w != 0), axis=(-2, -1))
    return bound, _no_value(bound, disagreeing)


def _no_value(bound: np.ndarray, disagreeing: np.ndarray) -> np.ndarray:
    """Where a disagreeing team's bound is not a finite normal float64 (it overflowed or underflowed)."""
    return disagreeing & ~((bound >= np.finfo(np.float64).tiny) & np.isfinite(bound))


def _beyond_text(bound: np.ndarray, beyond: np.ndarray) -> str:
    episodes = np.flatnonzero(np.ravel(beyond))
    side = (
        "above 1.8e308" if not np.all(np.ravel(bound)[episodes] < 1.0) else "below 2.2e-308 (not 0: the team disagrees)"
    )
    return (
        f"E* of episode(s) {episodes[:8].tolist()}{' ...' if len(episodes) > 8 else ''} is {side}, beyond float64; "
        "rescale the states or the deadline"
    )


def linear_energy_bound(model: LinearModel, z0: Any, settling_time: Any, offsets: Any = None) -> np.ndarray:
    """``E*`` for general linear agents ``z' = A z + B u`` per axis (docs: agent-models.md, "Agent models and formations").

    ``p_i = e^{A T_s} z_i(0)``, ``E* = sum_i (p_i - p̄)^T G(T_s)^{-1} (p_i - p̄)`` summed over axes,
    solved in the time- and state-scaled frame of :class:`~fxc_env.core.linear.IntervalMaps`
    (the Gramian is never inverted). With formation offsets ``h`` the agents agree on the
    formation error ``z_i - e^{A t} h_i``, so the bound is that of ``z_i(0) - h_i``.

    Args:
        model: the per-axis :class:`~fxc_env.core.linear.LinearModel`.
        z0: initial states ``(..., N, n, dim)`` (the engine's layout: n state components per axis).
        settling_time: ``T_s`` in seconds, > 0.
        offsets: formation offsets ``(N, n, dim)`` as full states, or None.

    Returns:
        ``(...)`` float64, in units of ``u^2 s``.

    Raises:
        ArgumentError naming ``settling_time`` where a disagreeing team's ``E*`` is beyond float64, as
        :func:`energy_bound` does.
    """
    if not isinstance(model, LinearModel):
        raise ArgumentError(f"model: expected a fxc_env.core.linear.LinearModel, got {type(model).__name__}")
    z = _states("z0", z0, 3)
    n = model.n_states
    if z.shape[-2] != n:
        raise ArgumentError(f"z0: expected shape (..., N, {n}, dim) for a model of {n} states, got {z.shape}")
    if offsets is not None:
        h = _states("offsets", offsets, 3)
        if h.shape != z.shape[-3:]:
            raise ArgumentError(f"offsets: expected shape {z.shape[-3:]}, got {h.shape}")
        z = z - h
    T = validation.real("settling_time", settling_time, positive=True)
    bound, beyond = _linear_bound(model.interval_maps([T]), z, T)
    if np.any(beyond):
        raise ArgumentError(f"settling_time: {_beyond_text(bound, beyond)} at T_s = {T:g} s")
    return bound


def _linear_bound(maps: Any, z: np.ndarray, T: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`linear_energy_bound`'s value ``(...)`` and where it has none in float64 ``(...)`` bool (no checks)."""
    per_axis = np.swapaxes(z, -1, -2)  # (..., N, dim, n)
    predicted = maps.free_motion(0, per_axis)
    delta = predicted - predicted.mean(axis=-3, keepdims=True)
    _, y = maps._solve(0, delta)  # y = L^{-1} S D^{-1} delta: |y|^2 / T = delta^T G^{-1} delta
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        bound = np.einsum("...i,...i->...", y / np.sqrt(T), y / np.sqrt(T)).sum(axis=(-2, -1))
    return bound, _no_value(bound, np.any(delta != 0, axis=(-3, -2, -1)))


def episode_energy_bound(model: LinearModel | None, z0: Any, settling_time: Any) -> np.ndarray:
    """``E*`` of every episode from its initial state ``z0`` ``(B, N, n, dim)`` (engine coordinates), ``(B,)``.

    ``model`` None is the double integrator (``z = (x, v)``, :func:`energy_bound`'s closed form);
    otherwise :func:`linear_energy_bound` with that model's Gramian. With formation offsets ``z0``
    is the formation error, so the bound is that of reaching the formation. NaN for an episode whose
    ``E*`` is beyond float64 (where :func:`energy_bound` raises), and for every episode where the Gramian over
    ``T_s`` is singular in float64 (an unstable ``A`` over a long ``T_s``): a step's metrics have no answer there.
    """
    z = np.asarray(z0, dtype=np.float64)
    T = float(settling_time)
    if model is None:
        bound, beyond = _double_integrator_bound(z[:, :, 0], z[:, :, 1], T)
    else:
        try:
            maps = model.interval_maps([T])
        except ArgumentError:  # the Gramian over T_s is singular in float64 (an unstable A over a long T_s)
            return np.full(z.shape[0], np.nan)
        bound, beyond = _linear_bound(maps, z, T)
    return np.where(beyond, np.nan, bound)


def root_set(topology: Topology) -> np.ndarray:
    """The roots: agents from which every agent can be reached in the (joint) graph, sorted ``(R,)``.

    For a fixed digraph with a directed spanning tree, the source strongly connected component;
    for a period, that of the union of its graphs (Theorem 2's joint graph).
    """
    forward = sp.csr_array(topology.union().T)  # forward[j, i] != 0: edge j -> i
    _, labels = csgraph.connected_components(forward, directed=True, connection="strong")
    coo = forward.tocoo()
    crossing = labels[coo.row] != labels[coo.col]
    has_incoming = np.zeros(labels.max() + 1, dtype=bool)
    has_incoming[labels[coo.col[crossing]]] = True
    sources = np.flatnonzero(~has_incoming)
    if len(sources) != 1:
        raise ArgumentError("topology: the (joint) graph has no directed spanning tree, so it has no root set")
    return np.flatnonzero(labels == sources[0])


def reach_intervals(topology: Topology) -> tuple[np.ndarray, np.ndarray]:
    """The roots, and per root the fewest intervals after which its initial state has reached every agent.

    Agent i measures its in-neighbours of ``G_k`` at ``t_k`` (graph ``k mod m`` of the period on
    interval k, from ``k = 0``, the first interval of every episode), so agent r's initial state
    reaches i along time-respecting paths only, one hop per interval. For a fixed digraph this is
    r's eccentricity, the longest shortest-path distance from r along the edges ``j -> i`` (i
    receives from j); for a period it is counted interval by interval through ``G_0, G_1, ...``.
    Only the roots of the (joint) graph reach every agent, so no other agent is listed.

    Returns:
        ``(roots, intervals)``: the roots sorted ``(R,)`` and their reach times ``(R,)`` int.
    """
    if not isinstance(topology, Topology):
        raise ArgumentError(f"topology: expected a fxc_env.core.graphs.Topology, got {type(topology).__name__}")
    n = topology.n_agents
    roots = root_set(topology)
    if n == 1:
        return roots, np.zeros(1, dtype=np.int64)
    if topology.period == 1:
        forward = sp.csr_array(topology.adjacency(0).T)  # forward[j, i] != 0: edge j -> i
        distances = csgraph.shortest_path(forward, method="D", unweighted=True, indices=roots)
        return roots, np.max(distances, axis=1).astype(np.int64)
    # reached[r, i]: root r's initial state has reached agent i. Each interval k adds the
    # receivers of G_{k mod m} whose senders were reached by t_k. Every period adds at least one
    # agent per root while the joint graph spans, so m N intervals always suffice.
    adjacency = [sp.csr_array(topology.adjacency(g), dtype=np.int32) for g in range(topology.period)]
    reached = np.zeros((n, len(roots)), dtype=bool)  # [i, r]
    reached[roots, np.arange(len(roots))] = True
    intervals = np.full(len(roots), -1, dtype=np.int64)
    for k in range(topology.period * n + 1):
        done = reached.all(axis=0) & (intervals < 0)
        intervals[done] = k
        if np.all(intervals >= 0):
            return roots, intervals
        reached |= (adjacency[k % topology.period] @ reached.astype(np.int32)) > 0
    raise AssertionError("the joint graph spans, so every root reaches every agent within m N intervals")


def radius_bound(topology: Topology) -> int:
    """The fewest sampling intervals in which **any** law can reach exact consensus: the graph's radius.

    ``min_r max_i dist(r -> i)`` over agents r, along the direction information flows (i receives
    from j: the edge ``j -> i``); for a switching period the time-respecting version: the fewest
    intervals K such that some agent's initial state has reached every agent by ``t_K`` through
    ``G_0, G_1, ...`` from interval 0 (:func:`reach_intervals`). Every law sees
    relative measurements only, so one agent's information must reach all. A directed ring of N:
    ``N - 1``; a path: ``N - 1`` from its end; a star: 1; a binary tree: its depth.

    Graphs drawn per episode (topology families) have one bound per drawn graph: the environment
    reports each episode's own. Random switching (a graph drawn per interval) has no fixed sequence
    to count through; the environment reports NaN there.

    Returns:
        The bound as an int (0 for a single agent).
    """
    return int(np.min(reach_intervals(topology)[1]))


def radius_centre(topology: Topology) -> int:
    """An agent attaining :func:`radius_bound` (the smallest index among them): a leader that reaches all soonest."""
    roots, intervals = reach_intervals(topology)
    return int(roots[np.argmin(intervals)])


def all_roots_bound(topology: Topology) -> int:
    """The fewest sampling intervals after which every agent can have heard from **every** root.

    The longest time-respecting distance from a root to an agent (:func:`reach_intervals`; a
    directed ring of N: ``N - 1``; a star: 1). A law whose consensus value depends on every root's
    initial state (the paper's, with ``xi`` positive on the roots, Theorems 1-2; the E*-optimal mean
    of the free-motion predictions) cannot reach exact consensus in fewer intervals. It bounds only
    such laws: any law is bounded by :func:`radius_bound`, which is never larger.

    Returns:
        The bound as an int (0 for a single agent).
    """
    return int(np.max(reach_intervals(topology)[1]))


def propagation_bound(topology: Topology) -> int:
    """Deprecated alias of :func:`all_roots_bound` (kept for one release; it is not a bound on every law).

    Warns:
        DeprecationWarning: use :func:`all_roots_bound` (laws whose value depends on every root) or
        :func:`radius_bound` (every law).
    """
    warnings.warn(
        "propagation_bound is deprecated: it is all_roots_bound, which bounds only laws whose value depends on "
        "every root; radius_bound bounds every law",
        DeprecationWarning,
        stacklevel=2,
    )
    return all_roots_bound(topology)


def settled_interval(errors: Any, tol: float = 1e-9) -> np.ndarray:
    """The interval after which the relative error stayed below ``tol``, per episode.

    Args:
        errors: relative disagreements ``D(t_k) / D(0)`` at the instants ``k = 0 .. K``,
            ``(..., K + 1)`` (batched over episodes in the leading dimensions); NaN counts as above.
        tol: the tolerance, > 0 (default 1e-9).

    Returns:
        ``(...)`` float64: the smallest k with ``errors[..., j] < tol`` for every ``j >= k``, i.e. the
        number of intervals the law used; ``inf`` where the error is not below ``tol`` at ``T_s``.
    """
    values = validation.real_array("errors", errors, "an array (..., K + 1)")
    if values.ndim < 1:
        raise ArgumentError(f"errors: expected an array (..., K + 1), got shape {values.shape}")
    tol = validation.real("tol", tol, positive=True)
    above = ~(values < tol)
    any_above = above.any(axis=-1)
    last = values.shape[-1] - 1 - np.argmax(above[..., ::-1], axis=-1)
    settled = np.where(any_above, last + 1.0, 0.0)
    return np.where(above[..., -1], np.inf, settled)
