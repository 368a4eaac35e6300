"""Offline gain design from the graph: Laplacian spectra, the gain tests, and the ZOH map.

Done once, before a run, by the designer who knows the graph (nothing here is available to an agent).
For the linear law ``u = -g L (x + gamma v)``:

- **Continuous time** (Yu, Chen & Cao 2010, Theorem 1): consensus on a digraph with a directed spanning tree
  iff ``gamma^2 > Im(mu)^2 / (Re(mu) |mu|^2)`` for every nonzero eigenvalue ``mu`` of ``g L``
  (:func:`gain_test_bound`; decay rate :func:`continuous_decay_rate`).
- **Sampled data with zero-order hold** at period h (Cao & Ren 2010): the one-sample map
  ``[[I - h^2 g L / 2, h I - h^2 g gamma L / 2], [-h g L, I - h g gamma L]]`` (:func:`zoh_radius`) must have
  spectral radius below one (over a switching period, the ordered product).
"""

from __future__ import annotations

from functools import reduce

import numpy as np
from scipy.sparse import csgraph

from fxc_env.core.graphs import Topology
from fxc_env.core.validation import ArgumentError

#: Largest N for which the design builds dense matrices.
DESIGN_LIMIT = 2000
#: Candidate damping ratios gamma, log-spaced (the design picks the best of them).
GAMMA_GRID = np.geomspace(1e-2, 1e3, 241)


def laplacians(topology: Topology) -> list[np.ndarray]:
    """Dense Laplacians ``L_g = D_g - A_g`` of the period's graphs, each ``(N, N)``."""
    if topology.n_agents > DESIGN_LIMIT:
        raise ArgumentError(
            f"topology: gain design is dense and limited to N <= {DESIGN_LIMIT}, got {topology.n_agents}"
        )
    return [topology.laplacian(g).toarray() for g in range(topology.period)]


def reduced(matrix: np.ndarray) -> np.ndarray:
    """``E L R`` for ``E = [I | -1]``, ``R = [I; 0]``: ``L`` on differences ``x_i - x_{N-1}``, ``(N-1, N-1)``.

    Valid for any ``L`` with ``L 1 = 0``; its eigenvalues are those of ``L`` but one zero.
    """
    return matrix[:-1, :-1] - matrix[-1:, :-1]


def _is_acyclic(laplacian: np.ndarray) -> bool:
    adjacency = (np.abs(laplacian) > 0) & ~np.eye(len(laplacian), dtype=bool)
    n_comp, _ = csgraph.connected_components(adjacency.T, directed=True, connection="strong")
    return n_comp == len(laplacian)


def nonzero_eigenvalues(laplacian: np.ndarray) -> np.ndarray:
    """The N-1 eigenvalues of ``L`` other than its (simple) zero, complex ``(N-1,)``.

    On an acyclic graph ``L`` is triangular in topological order: its diagonal, exactly (a solver would scatter
    a directed path's defective eigenvalue 1 over a circle of radius ``eps^(1/N)``).
    """
    if _is_acyclic(laplacian):
        return np.sort(np.diag(laplacian))[1:].astype(complex)  # the root's zero is the smallest
    return np.linalg.eigvals(reduced(laplacian)).astype(complex)


def design_eigenvalues(topology: Topology) -> np.ndarray:
    """Nonzero eigenvalues of the period's average Laplacian (the graph a fast-sampled law sees)."""
    return nonzero_eigenvalues(np.mean(laplacians(topology), axis=0))


def gain_test_bound(eigenvalues: np.ndarray, gain: float = 1.0) -> float:
    """Yu, Chen & Cao (2010): the least gamma, ``sqrt(max Im(mu)^2 / (Re(mu) |mu|^2))`` over ``mu = g lambda``.

    ``u = -g L (x + gamma v)`` reaches consensus iff ``gamma`` exceeds it. Infinite if an
    eigenvalue has ``Re <= 0`` (no gamma works).
    """
    mu = gain * np.asarray(eigenvalues, dtype=complex)
    if np.any(mu.real <= 0):
        return float("inf")
    return float(np.sqrt(np.max(mu.imag**2 / (mu.real * np.abs(mu) ** 2), initial=0.0)))


def _quadratic_roots(b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots of ``z^2 + b z + c`` (complex, broadcast)."""
    root = np.sqrt(b * b - 4.0 * c + 0j)
    return (-b + root) / 2.0, (-b - root) / 2.0


def continuous_decay_rate(eigenvalues: np.ndarray, gamma: np.ndarray | float, gain: float = 1.0) -> np.ndarray:
    """Least ``-Re(s)`` over the roots of ``s^2 + gamma mu s + mu``, ``mu = g lambda`` (1/s); ``gamma``'s shape."""
    mu = gain * np.asarray(eigenvalues, dtype=complex)
    gammas = np.asarray(gamma, dtype=float)[..., None]
    first, second = _quadratic_roots(gammas * mu, mu + 0 * gammas)
    return -np.max(np.maximum(first.real, second.real), axis=-1)


def design_gamma(eigenvalues: np.ndarray, gain: float = 1.0) -> float:
    """The gamma on :data:`GAMMA_GRID` with the fastest continuous decay (it passes the gain test)."""
    rates = continuous_decay_rate(eigenvalues, GAMMA_GRID, gain)
    return float(GAMMA_GRID[int(np.argmax(rates))])


def zoh_mode_radius(eigenvalues: np.ndarray, gamma: np.ndarray | float, gain: float, h: float) -> np.ndarray:
    """Spectral radius of the one-sample ZOH map, over the modes of a fixed graph; ``gamma``'s shape.

    Per eigenvalue ``mu = g lambda``: trace ``2 - h^2 mu / 2 - h gamma mu``, determinant ``1 - h gamma mu + h^2 mu / 2``.
    """
    mu = gain * np.asarray(eigenvalues, dtype=complex)
    gammas = np.asarray(gamma, dtype=float)[..., None]
    trace = 2.0 - h * h * mu / 2.0 - h * gammas * mu
    det = 1.0 - h * gammas * mu + h * h * mu / 2.0
    first, second = _quadratic_roots(-trace, det)
    return np.max(np.maximum(np.abs(first), np.abs(second)), axis=-1)


def zoh_radius(topology: Topology, gamma: float, gain: float, h: float) -> float:
    """Per-sample contraction of the exact ZOH map: ``rho(M_{m-1} ... M_0)^(1/m)`` on the disagreement.

    Below one iff ``u = -g L_k (x + gamma v)`` held for h seconds reaches consensus (Cao & Ren 2010).
    """
    mats = laplacians(topology)
    if len(mats) == 1:
        return float(zoh_mode_radius(nonzero_eigenvalues(mats[0]), gamma, gain, h))
    maps = [_zoh_map(reduced(L), gamma, gain, h) for L in mats]
    product = reduce(lambda acc, step: step @ acc, maps)
    return float(np.max(np.abs(np.linalg.eigvals(product))) ** (1.0 / len(mats)))


def _zoh_map(reduced_laplacian: np.ndarray, gamma: float, gain: float, h: float) -> np.ndarray:
    gl = gain * reduced_laplacian
    eye = np.eye(len(gl))
    top = np.hstack([eye - (h * h / 2.0) * gl, h * eye - (h * h * gamma / 2.0) * gl])
    bottom = np.hstack([-h * gl, eye - (h * gamma) * gl])
    return np.vstack([top, bottom])


def design_sampled_gains(topology: Topology, h: float, max_halvings: int = 12) -> tuple[float, float, float]:
    """``(gain, gamma, radius)`` for the ZOH law at period ``h``: the gamma with the smallest exact radius; the
    gain starts at 1 and is halved only while no gamma on the grid is stable."""
    mats = laplacians(topology)
    fixed = nonzero_eigenvalues(mats[0]) if len(mats) == 1 else None
    gain = 1.0
    for _ in range(max_halvings + 1):
        if fixed is not None:
            radii = zoh_mode_radius(fixed, GAMMA_GRID, gain, h)
            best = int(np.argmin(radii))
            gamma, radius = float(GAMMA_GRID[best]), float(radii[best])
        else:
            gamma, radius = _best_switching_gamma(topology, gain, h)
        if radius < 1.0:
            return gain, gamma, radius
        gain /= 2.0
    return gain * 2.0, gamma, radius


def _best_switching_gamma(topology: Topology, gain: float, h: float) -> tuple[float, float]:
    """Coarse-to-fine search of gamma for the period product (each try is an eigenvalue problem)."""
    coarse = GAMMA_GRID[::8]
    radii = [zoh_radius(topology, g, gain, h) for g in coarse]
    best = int(np.argmin(radii))
    low, high = coarse[max(best - 1, 0)], coarse[min(best + 1, len(coarse) - 1)]
    fine = np.geomspace(low, high, 13)
    radii_fine = [zoh_radius(topology, g, gain, h) for g in fine]
    pick = int(np.argmin(radii_fine))
    return float(fine[pick]), float(radii_fine[pick])
