"""Exact motion under an affine input (the paper's (10)-(11)): closed forms against scipy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from fxc_env.core import dynamics


def integrate(x, v, u0, u1, T, s_eval):
    """solve_ivp of x' = v, v' = u0 + (u1 - u0) s / T on [0, T]; returns x(s), v(s) (..., dim)."""
    x, v, u0, u1 = (np.asarray(a, dtype=float).ravel() for a in (x, v, u0, u1))
    n = x.size

    def rhs(s, y):
        return np.concatenate([y[n:], u0 + (u1 - u0) * s / T])

    sol = solve_ivp(rhs, (0.0, T), np.concatenate([x, v]), method="DOP853", rtol=1e-12, atol=1e-14, t_eval=s_eval)
    assert sol.success
    return sol.y[:n].T, sol.y[n:].T


def random_case(seed, dim=2):
    rng = np.random.default_rng(seed)
    x, v = rng.normal(scale=3.0, size=dim), rng.normal(size=dim)
    u0, u1 = rng.normal(scale=10.0, size=dim), rng.normal(scale=10.0, size=dim)
    T = float(rng.uniform(0.01, 5.0))
    return x, v, u0, u1, T


@pytest.mark.parametrize("seed", range(6))
def test_advance_matches_solve_ivp(seed):
    x, v, u0, u1, T = random_case(seed, dim=3)
    xs, vs = integrate(x, v, u0, u1, T, [T])
    x_next, v_next = dynamics.advance(x, v, u0, u1, T)
    scale = np.max(np.abs(np.concatenate([xs[-1], vs[-1]])))
    assert np.max(np.abs(x_next - xs[-1])) <= 1e-10 * scale
    assert np.max(np.abs(v_next - vs[-1])) <= 1e-10 * scale


@pytest.mark.parametrize("seed", range(4))
def test_state_inside_matches_solve_ivp_inside_the_interval(seed):
    x, v, u0, u1, T = random_case(seed)
    s = np.linspace(0.0, T, 17)
    xs, vs = integrate(x, v, u0, u1, T, s)
    x_s, v_s, u_s = dynamics.state_inside(x, v, u0, u1, T, s[:, None])
    scale = np.max(np.abs(np.concatenate([xs, vs])))
    assert np.max(np.abs(x_s - xs)) <= 1e-10 * scale
    assert np.max(np.abs(v_s - vs)) <= 1e-10 * scale
    np.testing.assert_allclose(u_s, u0 + (u1 - u0) * s[:, None] / T, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_state_inside_at_the_ends(seed):
    x, v, u0, u1, T = random_case(seed)
    x_end, v_end, u_end = dynamics.state_inside(x, v, u0, u1, T, T)
    x_next, v_next = dynamics.advance(x, v, u0, u1, T)
    np.testing.assert_allclose(x_end, x_next, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(v_end, v_next, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(u_end, u1, rtol=1e-13, atol=1e-13)
    x_0, v_0, u_0 = dynamics.state_inside(x, v, u0, u1, T, 0.0)
    np.testing.assert_array_equal(x_0, x)
    np.testing.assert_array_equal(v_0, v)
    np.testing.assert_array_equal(u_0, u0)


@pytest.mark.parametrize("seed", range(4))
def test_interval_energy_equals_quadrature(seed):
    _, _, u0, u1, T = random_case(seed, dim=3)
    expected = sum(
        quad(lambda s, a=a, b=b: (a + (b - a) * s / T) ** 2, 0.0, T, epsabs=0, epsrel=1e-13)[0]
        for a, b in zip(u0, u1, strict=True)
    )
    assert dynamics.interval_energy(u0, u1, T) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_interval_peak_equals_max_over_a_fine_grid(seed):
    _, _, u0, u1, T = random_case(seed, dim=3)
    s = np.linspace(0.0, T, 20001)[:, None]
    grid_peak = np.max(np.abs(u0 + (u1 - u0) * s / T))
    assert dynamics.interval_peak(u0, u1) == pytest.approx(grid_peak, rel=1e-12)


def test_interval_peak_with_a_sign_change():
    # |u| is smallest inside when u crosses zero; the peak stays at an end.
    assert dynamics.interval_peak(np.array([-3.0]), np.array([2.0])) == 3.0


@pytest.mark.parametrize("seed", range(6))
def test_input_from_plan_realises_the_plan(seed):
    rng = np.random.default_rng(100 + seed)
    x, v, a_x, a_v = (rng.normal(size=2) for _ in range(4))
    T = float(rng.uniform(0.001, 10.0))
    u0, u1 = dynamics.input_from_plan(a_x, a_v, T)
    x_next, v_next = dynamics.advance(x, v, u0, u1, T)
    np.testing.assert_allclose(x_next, x + T * v + a_x, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(v_next, v + a_v, rtol=1e-10, atol=1e-10)
    # Independently of advance(): integrate the input numerically.
    xs, vs = integrate(x, v, u0, u1, T, [T])
    np.testing.assert_allclose(xs[-1], x + T * v + a_x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(vs[-1], v + a_v, rtol=1e-9, atol=1e-9)
    # The minimum-energy plan of the paper's Remark 1: alpha = 6 a_x / T^2 - 2 a_v / T, beta = (6 a_v T - 12 a_x) / T^3.
    alpha = 6 * a_x / T**2 - 2 * a_v / T
    beta = (6 * a_v * T - 12 * a_x) / T**3
    np.testing.assert_allclose(u0, alpha, rtol=1e-12)
    np.testing.assert_allclose(u1, alpha + beta * T, rtol=1e-12, atol=1e-12 * np.abs(alpha).max())


def test_input_from_plan_is_minimum_energy():
    # Adding any input that leaves the end state alone (orthogonal to 1 and s on [0, T])
    # costs energy: the Legendre polynomial P2 on [0, T] is such an input.
    a_x, a_v, T = np.array([1.3]), np.array([-0.7]), 2.0
    u0, u1 = dynamics.input_from_plan(a_x, a_v, T)
    best = float(dynamics.interval_energy(u0, u1, T))

    def energy(c):
        def u(s):
            p2 = 0.5 * (3 * (2 * s / T - 1) ** 2 - 1)
            return u0[0] + (u1[0] - u0[0]) * s / T + c * p2

        return quad(lambda s: u(s) ** 2, 0, T, epsrel=1e-13)[0]

    assert energy(0.0) == pytest.approx(best, rel=1e-12)
    for c in (-1.0, -0.1, 0.1, 1.0):
        assert energy(c) > best


@pytest.mark.parametrize("seed", range(4))
def test_reference_plan_gives_the_closed_form_endpoints_and_energy(seed):
    rng = np.random.default_rng(200 + seed)
    e_x, e_v = rng.normal(size=3), rng.normal(size=3)
    T = float(rng.uniform(0.01, 3.0))
    # The paper's plan: a_v = -e_v, a_x = -e_x - T e_v (mean over {i} u N_i of coasted differences).
    u0, u1 = dynamics.input_from_plan(-e_x - T * e_v, -e_v, T)
    np.testing.assert_allclose(u0, -6 * e_x / T**2 - 4 * e_v / T, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(u1, 6 * e_x / T**2 + 2 * e_v / T, rtol=1e-11, atol=1e-11)
    energy = dynamics.interval_energy(u0, u1, T)
    expected = np.sum(12 * e_x**2 / T**3 + 12 * e_x * e_v / T**2 + 4 * e_v**2 / T)
    assert energy == pytest.approx(expected, rel=1e-10)
    # The input inside the interval is eq. (11) with t_k = 0, t_{k+1} = T.
    t = np.linspace(0.0, T, 9)[:, None]
    _, _, u_t = dynamics.state_inside(np.zeros(3), np.zeros(3), u0, u1, T, t)
    eq11 = -6 * (T - 2 * t) / T**3 * e_x - 2 * (2 * T - 3 * t) / T**2 * e_v
    np.testing.assert_allclose(u_t, eq11, rtol=1e-10, atol=1e-10 * np.abs(eq11).max())


def test_functions_broadcast_over_leading_dimensions():
    rng = np.random.default_rng(5)
    shape = (4, 3, 2)  # (K, N, dim)
    x, v, u0, u1 = (rng.normal(size=shape) for _ in range(4))
    T = rng.uniform(0.1, 1.0, size=(4, 1, 1))
    x_next, v_next = dynamics.advance(x, v, u0, u1, T)
    energy = dynamics.interval_energy(u0, u1, T)
    peak = dynamics.interval_peak(u0, u1)
    assert energy.shape == peak.shape == (4, 3)
    for k in range(4):
        for i in range(3):
            xk, vk = dynamics.advance(x[k, i], v[k, i], u0[k, i], u1[k, i], float(T[k, 0, 0]))
            np.testing.assert_allclose(x_next[k, i], xk, rtol=1e-15)
            np.testing.assert_allclose(v_next[k, i], vk, rtol=1e-15)
            assert energy[k, i] == pytest.approx(float(dynamics.interval_energy(u0[k, i], u1[k, i], T[k, 0, 0])))


def test_advance_in_place_equals_the_separate_closed_forms():
    from fxc_env.core.dynamics import advance, advance_into, interval_energy, interval_peak

    rng = np.random.default_rng(8)
    for dim in (1, 3):
        x, v, u0, u1 = (rng.normal(size=(4, 5, dim)) for _ in range(4))
        T = 0.37
        expected_x, expected_v = advance(x, v, u0, u1, T)
        energy, peak = advance_into(x, v, u0, u1, T, x, v)
        np.testing.assert_allclose(x, expected_x, rtol=1e-15, atol=1e-15)
        np.testing.assert_allclose(v, expected_v, rtol=1e-15, atol=1e-15)
        np.testing.assert_allclose(energy, interval_energy(u0, u1, T), rtol=1e-14)
        np.testing.assert_array_equal(peak, interval_peak(u0, u1))
