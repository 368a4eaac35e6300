"""Offline gain design: Laplacian spectra, Yu-Chen-Cao's test and the exact zero-order-hold map."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import PAPER_GRAPHS, adjacency_by_hand

from fxc_env import make_topology
from fxc_env.baselines.laws import design


def laplacian_by_hand(n, edges):
    a = adjacency_by_hand(n, edges)
    return np.diag(a.sum(axis=1)) - a


def zoh_map_by_hand(laplacian, gamma, gain, h):
    """The full 2N x 2N one-sample map of [x; v] under u = -g L (x + gamma v) held for h."""
    n = len(laplacian)
    eye = np.eye(n)
    u_x, u_v = -gain * laplacian, -gain * gamma * laplacian
    top = np.hstack([eye + h * h / 2 * u_x, h * eye + h * h / 2 * u_v])
    bottom = np.hstack([h * u_x, eye + h * u_v])
    return np.vstack([top, bottom])


def disagreement_radius(matrix):
    """Largest |eigenvalue| once the two consensus eigenvalues (both 1) are set aside."""
    values = np.linalg.eigvals(matrix)
    keep = np.argsort(np.abs(values - 1.0))[2:]
    return np.max(np.abs(values[keep]))


def test_gain_test_is_exactly_the_hurwitz_boundary():
    rng = np.random.default_rng(0)
    eigenvalues = rng.uniform(0.1, 3.0, 40) + 1j * rng.uniform(-3.0, 3.0, 40)
    for mu in eigenvalues:
        bound = design.gain_test_bound([mu])
        assert design.continuous_decay_rate([mu], bound * 1.001) > 0
        assert design.continuous_decay_rate([mu], bound * 0.999) < 0


def test_undirected_graphs_need_no_damping_bound():
    assert design.gain_test_bound(np.array([0.5, 2.0, 4.0], dtype=complex)) == 0.0
    assert design.gain_test_bound(np.array([1.0, 0.0 - 0.1j])) == float("inf")


def test_directed_path_eigenvalues_are_exact_despite_the_jordan_block():
    topology = make_topology("path", 60)
    values = design.nonzero_eigenvalues(topology.laplacian().toarray())
    np.testing.assert_array_equal(values, np.ones(59))


def test_nonzero_eigenvalues_of_a_cyclic_graph_match_numpy():
    topology = make_topology("random", 15, seed=4)
    laplacian = topology.laplacian().toarray()
    full = np.linalg.eigvals(laplacian)
    full = np.delete(full, np.argmin(np.abs(full)))
    ours = design.nonzero_eigenvalues(laplacian)
    np.testing.assert_allclose(np.sort_complex(ours), np.sort_complex(full), atol=1e-10)


@pytest.mark.parametrize("h", [0.05, 0.8])
def test_zoh_radius_of_a_fixed_graph_equals_the_full_map(h):
    topology = make_topology("ring", 7)
    by_hand = disagreement_radius(zoh_map_by_hand(laplacian_by_hand(7, topology.edges[0]), 1.7, 0.6, h))
    assert design.zoh_radius(topology, 1.7, 0.6, h) == pytest.approx(by_hand, rel=1e-9)


def test_zoh_radius_of_a_switching_period_is_that_of_the_ordered_product():
    topology = make_topology(PAPER_GRAPHS)
    maps = [zoh_map_by_hand(laplacian_by_hand(6, g), 3.0, 1.0, 0.4) for g in PAPER_GRAPHS]
    product = maps[2] @ maps[1] @ maps[0]
    expected = disagreement_radius(product) ** (1 / 3)
    assert design.zoh_radius(topology, 3.0, 1.0, 0.4) == pytest.approx(expected, rel=1e-7)


def test_sampled_design_lowers_the_gain_only_when_no_gamma_is_stable():
    ring = make_topology("ring", 6)
    unit_gain = design.zoh_mode_radius(
        design.nonzero_eigenvalues(ring.laplacian().toarray()), design.GAMMA_GRID, 1.0, 0.8
    )
    assert unit_gain.min() >= 1.0  # h = 0.8 s is too long for the unit-gain law on the 6-ring
    gain, gamma, radius = design.design_sampled_gains(ring, 0.8)
    assert gain < 1.0 and radius < 1.0
    assert design.zoh_radius(ring, gamma, gain, 0.8) == pytest.approx(radius)
    gain, _, radius = design.design_sampled_gains(ring, 0.1)
    assert gain == 1.0 and radius < 1.0
