"""General linear agents (fxc_env.core.linear): minimum-energy steering against scipy and exact arithmetic."""

from __future__ import annotations

import math
import warnings
from fractions import Fraction

import numpy as np
import pytest
from scipy.integrate import quad_vec, solve_ivp
from scipy.linalg import expm

from fxc_env.core import dynamics, graphs, schedules
from fxc_env.core.linear import (
    MODEL_NAMES,
    PEAK_GRID_POINTS,
    LinearModel,
    UnstableModelWarning,
    final_value,
    formation_offsets,
    is_double_integrator,
    model_matrices,
    offset_at,
)
from fxc_env.core.validation import ArgumentError, ArgumentTypeError

NAMED = [
    ("single_integrator", {}),
    ("double_integrator", {}),
    ("integrator_chain", {"order": 1}),
    ("integrator_chain", {"order": 2}),
    ("integrator_chain", {"order": 3}),
    ("integrator_chain", {"order": 4}),
    ("damped", {}),
    ("damped", {"damping": 2.0}),
    ("oscillator", {}),
    ("oscillator", {"frequency": 3.0}),
]
NAMED_IDS = [name + "".join(f"-{k}={v}" for k, v in kw.items()) for name, kw in NAMED]


def input_at(model, lam, T, s):
    """``u(s) = B^T e^{A^T (T - s)} lambda`` from scipy's expm, for lambda ``(M, n)``: ``(M, m)``."""
    return lam @ expm(model.A * (T - s)) @ model.B


def simulate_interval(model, z0, lam, T, s_eval=None):
    """solve_ivp (DOP853, rtol 1e-12) of ``z' = A z + B u(s)`` plus ``E' = |u|^2`` for rows ``z0`` ``(M, n)``.

    Returns ``z(s)`` ``(P, M, n)`` and ``E(s)`` ``(P, M)`` at ``s_eval`` (default ``[T]``).
    """
    z0, lam = np.atleast_2d(z0), np.atleast_2d(lam)
    rows, n = z0.shape
    A, B = model.A, model.B

    def rhs(s, y):
        u = input_at(model, lam, T, s)
        z = y[: rows * n].reshape(rows, n)
        return np.concatenate([(z @ A.T + u @ B.T).ravel(), np.sum(u * u, axis=1)])

    u_scale = max(np.max(np.abs(input_at(model, lam, T, s))) for s in (0.0, T / 2, T))
    atol = np.concatenate(
        [np.full(rows * n, 1e-14 * max(1.0, np.max(np.abs(z0)))), np.full(rows, 1e-15 * u_scale**2 * T + 1e-300)]
    )
    s_eval = [T] if s_eval is None else s_eval
    y0 = np.concatenate([z0.ravel(), np.zeros(rows)])
    sol = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-12, atol=atol, t_eval=s_eval)
    assert sol.success
    return sol.y[: rows * n].T.reshape(-1, rows, n), sol.y[rows * n :].T


def relative(a, b):
    """Normwise relative difference ``max|a - b| / max|b|``."""
    return float(np.max(np.abs(np.asarray(a) - b)) / np.max(np.abs(b)))


# --------------------------------------------------------------------------- one interval
@pytest.mark.parametrize(("name", "kw"), NAMED, ids=NAMED_IDS)
@pytest.mark.slow
def test_one_interval_matches_solve_ivp(name, kw):
    model = LinearModel.named(name, **kw)
    n = model.n_states
    rng = np.random.default_rng(len(name) + n)
    lengths = [0.37, 2.5]
    maps = model.interval_maps(lengths)
    for k, T in enumerate(lengths):
        z0, delta = rng.normal(size=(3, n)), rng.normal(size=(3, n))
        z_next, energy, peak = maps.steer(k, z0, delta)
        np.testing.assert_allclose(z_next, z0 @ expm(model.A * T).T + delta, rtol=1e-12, atol=1e-12)
        lam = maps.costate(k, delta)
        s = np.linspace(0.0, T, 9)
        z_ivp, e_ivp = simulate_interval(model, z0, lam, T, s)
        assert relative(z_next, z_ivp[-1]) <= 1e-9
        assert relative(energy, e_ivp[-1]) <= 1e-9
        # Inside the interval: state and input.
        z_in, u_in = maps.state_inside(k, z0, delta, s)
        assert z_in.shape == (9, 3, n) and u_in.shape == (9, 3, 1)
        assert relative(z_in, z_ivp) <= 1e-9
        u_ref = np.stack([input_at(model, lam, T, si) for si in s])
        assert relative(u_in, u_ref) <= 1e-10
        np.testing.assert_allclose(z_in[0], z0, rtol=0, atol=1e-14)
        assert relative(z_in[-1], z_next) <= 1e-10
        # Peak: exact for the polynomial inputs, the 65-point grid otherwise.
        dense = np.max(np.abs(np.stack([input_at(model, lam, T, si) for si in np.linspace(0.0, T, 2001)])), axis=(0, 2))
        if model.polynomial_input:
            assert np.all(peak >= dense * (1 - 1e-12))
            assert np.all(peak <= dense * (1 + 1e-6))
        else:
            grid = np.stack([input_at(model, lam, T, si) for si in np.linspace(0.0, T, PEAK_GRID_POINTS)])
            np.testing.assert_allclose(peak, np.max(np.abs(grid), axis=(0, 2)), rtol=1e-11)
            assert np.all(peak <= dense * (1 + 1e-12))
            assert np.all(peak >= dense * (1 - 1e-3))


def test_general_pair_with_two_inputs_matches_solve_ivp():
    rng = np.random.default_rng(7)
    A = rng.normal(size=(3, 3))
    B = rng.normal(size=(3, 2))
    model = LinearModel(A, B)
    assert model.n_states == 3 and model.n_inputs == 2 and not model.polynomial_input
    T = 0.8
    maps = model.interval_maps([T])
    z0, delta = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    z_next, energy, peak = maps.steer(0, z0, delta)
    lam = maps.costate(0, delta)
    z_ivp, e_ivp = simulate_interval(model, z0, lam, T)
    assert relative(z_next, z_ivp[-1]) <= 1e-9
    assert relative(energy, e_ivp[-1]) <= 1e-9
    G = model.gramian(T)
    G_quad, _ = quad_vec(lambda s: expm(A * s) @ B @ B.T @ expm(A.T * s), 0.0, T, epsabs=1e-14, epsrel=1e-12)
    assert relative(G, G_quad) <= 1e-10
    np.testing.assert_allclose(np.einsum("mi,ij,mj->m", delta, np.linalg.inv(G), delta), energy, rtol=1e-10)
    s = np.linspace(0.0, T, PEAK_GRID_POINTS)
    grid = np.stack([input_at(model, lam, T, si) for si in s])
    np.testing.assert_allclose(peak, np.max(np.abs(grid), axis=(0, 2)), rtol=1e-11)
    _, u_in = maps.state_inside(0, z0, delta, s)
    assert u_in.shape == (PEAK_GRID_POINTS, 4, 2)
    assert relative(u_in, grid) <= 1e-10


# --------------------------------------------------------------------------- whole episode
def episode_check(model, settling_time=10.0, n_intervals=200):
    """6 agents on a directed ring, the paper's schedule: every interval against solve_ivp, then consensus."""
    topology = graphs.named_topology("ring", 6)
    averaging = topology.averaging_matrix(0).toarray()
    xi = topology.consensus_weights()
    schedule = schedules.make_schedule(settling_time, n_intervals, "paper")
    maps = model.interval_maps(schedule.intervals)
    n, dim = model.n_states, 2
    rng = np.random.default_rng(11)
    z0 = rng.normal(size=(6, dim, n))
    z = z0.copy()
    A, B = model.A, model.B
    worst_state, worst_energy = 0.0, 0.0
    for k, T in enumerate(schedule.intervals):
        error = np.einsum("ij,jdn->idn", averaging, z) - z  # mean over {i} u N_i of (z_j - z_i)
        delta = maps.free_motion(k, error)
        z_next, energy, _ = maps.steer(k, z, delta)
        # The same inputs, integrated with the costate p(s) = e^{A^T (T - s)} lambda as extra states.
        rows = z.reshape(-1, n)
        p0 = maps.costate(k, delta).reshape(-1, n) @ expm(A * T)
        count = rows.shape[0]

        def rhs(_s, y, count=count):
            zs, ps = y[: count * n].reshape(count, n), y[count * n : 2 * count * n].reshape(count, n)
            u = ps @ B
            return np.concatenate([(zs @ A.T + u @ B.T).ravel(), (-ps @ A).ravel(), np.sum(u * u, axis=1)])

        expected_energy = energy.reshape(-1)
        atol = np.concatenate(
            [
                np.tile(1e-14 * np.max(np.abs(rows), axis=0) + 1e-300, count),  # per component: the
                np.tile(1e-14 * np.max(np.abs(p0), axis=0) + 1e-300, count),  # scales differ by T^-2
                np.full(count, 1e-14 * np.max(expected_energy) + 1e-300),
            ]
        )
        y0 = np.concatenate([rows.ravel(), p0.ravel(), np.zeros(count)])
        sol = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-13, atol=atol)
        assert sol.success
        worst_state = max(worst_state, relative(z_next.reshape(-1), sol.y[: count * n, -1]))
        worst_energy = max(worst_energy, relative(expected_energy, sol.y[2 * count * n :, -1]))
        z = z_next
    assert worst_state <= 1e-9
    assert worst_energy <= 1e-9
    target = final_value(model, xi, z0, schedule.settling_time)
    spread = np.max(np.abs(z0 - z0.mean(axis=0)))
    assert np.max(np.abs(z - target)) <= 1e-8 * spread


@pytest.mark.parametrize(
    ("name", "kw"),
    [("double_integrator", {}), ("integrator_chain", {"order": 3}), ("damped", {}), ("oscillator", {})],
    ids=["double_integrator", "integrator_chain-3", "damped", "oscillator"],
)
@pytest.mark.slow
def test_episode_on_a_ring_matches_solve_ivp_and_reaches_the_final_value(name, kw):
    episode_check(LinearModel.named(name, **kw))


# --------------------------------------------------------------------------- double integrator closed forms
@pytest.mark.parametrize("seed", range(5))
def test_double_integrator_matches_the_closed_forms(seed):
    rng = np.random.default_rng(seed)
    A, B = model_matrices("double_integrator")
    model = LinearModel(A, B)
    assert model.is_double_integrator and is_double_integrator(A, B)
    T = float(rng.uniform(0.01, 5.0))
    maps = model.interval_maps([T])
    x, v = rng.normal(scale=3.0, size=(4, 3)), rng.normal(size=(4, 3))
    a_x, a_v = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    Z, delta = np.stack([x, v], axis=-1), np.stack([a_x, a_v], axis=-1)
    z_next, energy, peak = maps.steer(0, Z, delta)
    u0, u1 = dynamics.input_from_plan(a_x, a_v, T)
    x_next, v_next = dynamics.advance(x, v, u0, u1, T)
    reference = np.stack([x_next, v_next], axis=-1)
    assert relative(z_next, reference) <= 1e-12
    np.testing.assert_allclose(energy, (u0 * (u0 + u1) + u1 * u1) * T / 3, rtol=1e-12)
    np.testing.assert_allclose(energy.sum(axis=-1), dynamics.interval_energy(u0, u1, T), rtol=1e-12)
    np.testing.assert_allclose(peak, np.maximum(np.abs(u0), np.abs(u1)), rtol=1e-12)
    np.testing.assert_allclose(peak.max(axis=-1), dynamics.interval_peak(u0, u1), rtol=1e-12)
    lam = maps.costate(0, delta)
    np.testing.assert_allclose(lam[..., 1] + T * lam[..., 0], u0, rtol=1e-12, atol=1e-12 * np.max(np.abs(u0)))
    np.testing.assert_allclose(lam[..., 1], u1, rtol=1e-12, atol=1e-12 * np.max(np.abs(u1)))
    s = np.linspace(0.0, T, 7)
    z_in, u_in = maps.state_inside(0, Z, delta, s)
    x_s, v_s, u_s = dynamics.state_inside(x, v, u0, u1, T, s[:, None, None])
    assert relative(z_in, np.stack([x_s, v_s], axis=-1)) <= 1e-12
    assert relative(u_in[..., 0], u_s) <= 1e-12


def test_double_integrator_detection():
    assert is_double_integrator([[0, 1], [0, 0]], [0, 1])
    assert is_double_integrator(*model_matrices("integrator_chain", order=2))
    for name, kw in NAMED:
        if name != "double_integrator" and kw.get("order") != 2:
            assert not is_double_integrator(*model_matrices(name, **kw))
    assert not is_double_integrator([[0, 1], [0, 0]], [[0], [2]])
    assert not is_double_integrator("A", None)
    assert not LinearModel.named("damped").is_double_integrator


# --------------------------------------------------------------------------- short intervals
def chain_gramian_exact(T: Fraction, n: int) -> list[list[Fraction]]:
    """``G(T)`` of the integrator chain of order n in exact rationals (state i = i-th derivative)."""
    a = [n - 1 - i for i in range(n)]
    return [
        [T ** (a[i] + a[j] + 1) / (math.factorial(a[i]) * math.factorial(a[j]) * (a[i] + a[j] + 1)) for j in range(n)]
        for i in range(n)
    ]


def exact_solve(G: list[list[Fraction]], b: list[Fraction]) -> list[Fraction]:
    """Gaussian elimination in exact rationals."""
    n = len(b)
    M = [[*row, rhs] for row, rhs in zip(G, b, strict=True)]
    for c in range(n):
        pivot = next(r for r in range(c, n) if M[r][c] != 0)
        M[c], M[pivot] = M[pivot], M[c]
        for r in range(n):
            if r != c and M[r][c] != 0:
                f = M[r][c] / M[c][c]
                M[r] = [x - f * y for x, y in zip(M[r], M[c], strict=True)]
    return [M[i][n] / M[i][i] for i in range(n)]


@pytest.mark.parametrize("T", [1e-6, 1e-4, 1e-2, 1.0, 30.0])
def test_chain_of_order_four_achieves_the_plan_at_short_intervals(T):
    model = LinearModel.named("integrator_chain", order=4)
    maps = model.interval_maps([T])
    assert maps.scaled_condition[0] < 1e4
    rng = np.random.default_rng(3)
    natural = T ** np.arange(3, -1, -1.0)  # position ~ T^3, ..., highest derivative ~ 1
    G = chain_gramian_exact(Fraction(T), 4)
    for delta in (rng.normal(size=4) * natural, rng.normal(size=4)):
        lam = maps.costate(0, delta)
        achieved = [sum(G[i][j] * Fraction(float(lam[j])) for j in range(4)) for i in range(4)]
        error = np.array([float(achieved[i] - Fraction(float(delta[i]))) for i in range(4)])
        # Normwise in the scaled frame, for any plan.
        assert np.max(np.abs(error / natural)) <= 1e-9 * np.max(np.abs(delta / natural))
        exact_delta = [Fraction(float(d)) for d in delta]
        exact_energy = float(sum(d * x for d, x in zip(exact_delta, exact_solve(G, exact_delta), strict=True)))
        _, energy, _ = maps.steer(0, np.zeros(4), delta)
        assert abs(energy - exact_energy) <= 1e-9 * exact_energy
    # A plan of natural size is achieved componentwise, also through the state inside at s = T.
    delta = rng.normal(size=4) * natural
    lam = maps.costate(0, delta)
    achieved = [sum(G[i][j] * Fraction(float(lam[j])) for j in range(4)) for i in range(4)]
    assert all(abs(float(achieved[i]) - delta[i]) <= 1e-9 * abs(delta[i]) for i in range(4))
    z0 = rng.normal(size=4) * natural
    z_end, _ = maps.state_inside(0, z0, delta, T)
    np.testing.assert_allclose(z_end - maps.free_motion(0, z0), delta, rtol=1e-9, atol=0)
    # The peak of the cubic input, against dense sampling of the same polynomial.
    _, _, peak = maps.steer(0, z0, delta)
    tau = np.linspace(0.0, T, 4001)
    u = sum(lam[j] * tau ** (3 - j) / math.factorial(3 - j) for j in range(4))
    assert np.max(np.abs(u)) <= peak * (1 + 1e-9)
    assert np.max(np.abs(u)) >= peak * (1 - 1e-6)


def test_frame_of_a_chain_does_not_depend_on_the_interval():
    model = LinearModel.named("integrator_chain", order=4)
    maps = model.interval_maps([1e-30, 1e-6, 1.0, 1e6])
    np.testing.assert_array_equal(maps.a_hat, np.broadcast_to(np.eye(4, k=1), (4, 4, 4)))
    np.testing.assert_allclose(maps.scaled_condition, maps.scaled_condition[0], rtol=1e-12)
    np.testing.assert_array_equal(model.levels, [3, 2, 1, 0])


# --------------------------------------------------------------------------- other helpers
@pytest.mark.parametrize(("name", "kw"), NAMED, ids=NAMED_IDS)
def test_free_motion_and_gramian(name, kw):
    model = LinearModel.named(name, **kw)
    A, B = model.A, model.B
    for t in (0.0, 1e-3, 0.6, 7.0):
        np.testing.assert_allclose(model.free_motion_matrix(t), expm(A * t), rtol=1e-13, atol=1e-13)
    t = np.array([[0.2, 1.5]])
    assert model.free_motion_matrix(t).shape == (1, 2, model.n_states, model.n_states)
    G_quad, _ = quad_vec(lambda s: expm(A * s) @ B @ B.T @ expm(A.T * s), 0.0, 1.3, epsabs=1e-15, epsrel=1e-12)
    assert relative(model.gramian(1.3), G_quad) <= 1e-10


def test_model_matrices():
    A, B = model_matrices("integrator_chain", order=3)
    np.testing.assert_array_equal(A, [[0, 1, 0], [0, 0, 1], [0, 0, 0]])
    np.testing.assert_array_equal(B, [[0], [0], [1]])
    A, B = model_matrices("damped")
    np.testing.assert_array_equal(A, [[0, 1], [0, -0.5]])
    A, _ = model_matrices("damped", damping=2)
    assert A[1, 1] == -2
    A, _ = model_matrices("oscillator", frequency=3)
    np.testing.assert_array_equal(A, [[0, 1], [-9, 0]])
    np.testing.assert_array_equal(model_matrices("oscillator")[0], [[0, 1], [-1, 0]])
    np.testing.assert_array_equal(model_matrices("single_integrator")[0], [[0]])
    assert set(MODEL_NAMES) == {name for name, _ in NAMED}


def test_broadcasting_and_empty_batches():
    model = LinearModel.named("integrator_chain", order=3)
    maps = model.interval_maps([0.5, 0.25])
    rng = np.random.default_rng(5)
    z, delta = rng.normal(size=(3, 1, 3)), rng.normal(size=(1, 4, 3))
    z_next, energy, peak = maps.steer(1, z, delta)
    assert z_next.shape == (3, 4, 3) and energy.shape == (3, 4) and peak.shape == (3, 4)
    single = maps.steer(1, z[2, 0], delta[0, 3])
    np.testing.assert_allclose(z_next[2, 3], single[0], rtol=1e-15)
    assert energy[2, 3] == pytest.approx(single[1], rel=1e-14) and peak[2, 3] == pytest.approx(single[2], rel=1e-14)
    z_in, u_in = maps.state_inside(1, z, delta, np.array([[0.0, 0.1], [0.2, 0.25]]))
    assert z_in.shape == (2, 2, 3, 4, 3) and u_in.shape == (2, 2, 3, 4, 1)
    empty = maps.steer(0, np.zeros((0, 2, 3)), np.zeros((0, 2, 3)))
    assert [a.shape for a in empty] == [(0, 2, 3), (0, 2), (0, 2)]
    grid_maps = LinearModel.named("oscillator").interval_maps([0.5])
    assert [a.shape for a in grid_maps.steer(0, np.zeros((0, 2)), np.zeros((0, 2)))] == [(0, 2), (0,), (0,)]
    assert np.all(maps.steer(0, z, np.zeros(3))[1] == 0)


def test_formations_and_final_value():
    model = LinearModel.named("integrator_chain", order=3)
    rng = np.random.default_rng(9)
    positions = rng.normal(size=(5, 2))
    h = formation_offsets(positions, 5, 2, 3)
    assert h.shape == (5, 2, 3)
    np.testing.assert_array_equal(h[..., 0], positions)
    np.testing.assert_array_equal(h[..., 1:], 0)
    full = rng.normal(size=(5, 2, 3))
    np.testing.assert_array_equal(formation_offsets(full, 5, 2, 3), full)
    F_t = model.free_motion_matrix(2.0)
    np.testing.assert_allclose(offset_at(full, F_t), np.einsum("ij,adj->adi", expm(model.A * 2.0), full), rtol=1e-13)
    # The double integrator's Theorems 1-2: x* = xi^T x(0) + t xi^T v(0), v* = xi^T v(0).
    di = LinearModel.named("double_integrator")
    xi = np.array([0.5, 0.3, 0.2])
    Z0 = rng.normal(size=(3, 2, 2))
    target = final_value(di, xi, Z0, 4.0)
    np.testing.assert_allclose(target[:, 0], xi @ Z0[:, :, 0] + 4.0 * (xi @ Z0[:, :, 1]), rtol=1e-13)
    np.testing.assert_allclose(target[:, 1], xi @ Z0[:, :, 1], rtol=1e-13)
    batched = final_value(di, np.stack([xi, xi[::-1]]), np.stack([Z0, Z0]), 4.0)
    assert batched.shape == (2, 2, 2)
    np.testing.assert_allclose(batched[0], target, rtol=1e-15)


# --------------------------------------------------------------------------- bad inputs
def test_uncontrollable_pair_is_refused_with_the_rank():
    with pytest.raises(ArgumentError, match=r"^A, B: .*rank 1 < n = 2"):
        LinearModel(np.diag([1.0, 2.0]), [[1.0], [0.0]])
    with pytest.raises(ArgumentError, match=r"^A, B: .*rank 2 < n = 3"):
        LinearModel(np.eye(3, k=1), [[0.0], [1.0], [0.0]])


@pytest.mark.parametrize(
    ("A", "B", "match", "error"),
    [
        (np.zeros((2, 3)), [[0], [1]], r"^A: expected a square", ArgumentError),
        (np.zeros(2), [[0], [1]], r"^A: expected a square", ArgumentError),
        (np.zeros((0, 0)), np.zeros((0, 1)), r"^A: expected a square", ArgumentError),
        ([[0, 1], [0, np.nan]], [[0], [1]], r"^A: every entry must be finite", ArgumentError),
        ([["a", "b"], ["c", "d"]], [[0], [1]], r"^A: expected", ArgumentTypeError),
        ([[0, 1], [0, 0]], [[0], [1], [2]], r"^B: expected an \(n, m\) = \(2, m\)", ArgumentError),
        ([[0, 1], [0, 0]], np.zeros((2, 0)), r"^B: expected an \(n, m\)", ArgumentError),
        ([[0, 1], [0, 0]], [[0], [np.inf]], r"^B: every entry must be finite", ArgumentError),
        ([[0, 1], [0, 0]], None, r"^B: expected", ArgumentTypeError),
    ],
)
def test_bad_matrices_are_refused_by_name(A, B, match, error):
    with pytest.raises(error, match=match):
        LinearModel(A, B)


def test_bad_model_names_and_parameters():
    with pytest.raises(ArgumentError, match=r"^agent_model: expected one of"):
        model_matrices("triple_integrator")
    with pytest.raises(ArgumentError, match=r"^order: expected an integer in \[1, 4\], got 5"):
        model_matrices("integrator_chain", order=5)
    with pytest.raises(ArgumentError, match=r"^order: "):
        model_matrices("integrator_chain", order=0)
    with pytest.raises(ArgumentTypeError, match=r"^order: "):
        model_matrices("integrator_chain", order=2.0)
    with pytest.raises(ArgumentError, match=r"^order: only agent_model = 'integrator_chain'"):
        model_matrices("damped", order=3)
    with pytest.raises(ArgumentError, match=r"^damping: "):
        model_matrices("damped", damping=-1.0)
    with pytest.raises(ArgumentError, match=r"^damping: only"):
        model_matrices("oscillator", damping=1.0)
    with pytest.raises(ArgumentError, match=r"^frequency: "):
        model_matrices("oscillator", frequency=float("nan"))
    with pytest.raises(ArgumentError, match=r"^agent_model: "):
        LinearModel.named("chain")


def test_bad_arguments_of_the_operations():
    model = LinearModel.named("double_integrator")
    with pytest.raises(ArgumentError, match=r"^intervals: "):
        model.interval_maps([0.1, -1.0])
    with pytest.raises(ArgumentError, match=r"^intervals: "):
        model.interval_maps([])
    with pytest.raises(
        ArgumentError,
        match=r"^intervals: the controllability Gramian is numerically singular or not finite over the interval T = 1000\.0 s",
    ):
        LinearModel(np.diag([1.0, 2.0]), [[1.0], [1.0]]).interval_maps([0.5, 1000.0])  # e^{4000} overflows
    maps = model.interval_maps([0.1, 0.2])
    with pytest.raises(ArgumentError, match=r"^k: "):
        maps.steer(2, np.zeros(2), np.zeros(2))
    with pytest.raises(ArgumentError, match=r"^Z: expected an array \(\.\.\., n\) with a last axis of n = 2"):
        maps.steer(0, np.zeros(3), np.zeros(2))
    with pytest.raises(ArgumentError, match=r"^delta: "):
        maps.steer(0, np.zeros((4, 2)), np.zeros((3, 2)))
    with pytest.raises(ArgumentError, match=r"^s: every offset must lie in \[0, T_k\]"):
        maps.state_inside(0, np.zeros(2), np.zeros(2), [0.0, 0.2])
    with pytest.raises(ArgumentError, match=r"^t: "):
        model.free_motion_matrix(-1.0)
    with pytest.raises(ArgumentError, match=r"^formation_offsets: expected an array of shape \(N, dim\) = \(6, 2\)"):
        formation_offsets(np.zeros((6, 3)), 6, 2, 2)
    with pytest.raises(ArgumentError, match=r"^formation_offsets: "):
        formation_offsets(np.zeros((6, 2, 3)), 6, 2, 2)
    with pytest.raises(ArgumentError, match=r"^formation_offsets: every entry must be finite"):
        formation_offsets(np.full((6, 2), np.nan), 6, 2, 2)
    with pytest.raises(ArgumentTypeError, match=r"^formation_offsets: "):
        formation_offsets("line", 6, 2, 2)
    with pytest.raises(ArgumentError, match=r"^xi: "):
        final_value(model, np.ones(4) / 4, np.zeros((3, 2, 2)), 1.0)
    with pytest.raises(ArgumentError, match=r"^Z0: "):
        final_value(model, np.ones(3) / 3, np.zeros((3, 2, 3)), 1.0)


def _gramian_by_quadrature(model: LinearModel, T: float) -> np.ndarray:
    """``int_0^T e^{A s} B B^T e^{A^T s} ds`` by adaptive quadrature (independent of Van Loan)."""

    def integrand(s: float) -> np.ndarray:
        F = expm(model.A * s)
        return (F @ model.B @ model.B.T @ F.T).ravel()

    n = model.n_states
    return quad_vec(integrand, 0.0, T, epsabs=0.0, epsrel=1e-13)[0].reshape(n, n)


@pytest.mark.slow
@pytest.mark.parametrize("damping", [4.0, 50.0, 1e3])
def test_a_heavily_damped_gramian_over_the_paper_s_first_interval_is_accurate(damping):
    """Over T_1 = 12.16 s a damping of 4 /s or more made Van Loan's block exponential lose every digit."""
    model = LinearModel.named("damped", damping=damping)
    T = schedules.make_schedule(20.0, 200, "paper").intervals[0]
    reference = _gramian_by_quadrature(model, T)
    assert np.allclose(model.gramian(T), reference, rtol=1e-11, atol=0.0)
    maps = model.interval_maps(schedules.make_schedule(20.0, 200, "paper").intervals)
    assert np.all(maps.scaled_condition < 1e3)


@pytest.mark.slow
def test_a_damped_agent_reaches_consensus_on_the_paper_schedule():
    import fxc_env

    trajectory = fxc_env.simulate(scenario="paper_fig1", agent_model={"name": "damped", "damping": 4.0}, seed=0)
    assert trajectory.metrics.relative_deadline_error < 1e-9


@pytest.mark.slow
def test_a_model_that_outgrows_float64_within_the_horizon_is_refused_at_construction():
    import fxc_env

    unstable = ([[20.0, 1.0], [0.0, 20.0]], [[0.0], [1.0]])
    with pytest.raises(ArgumentError, match=r"agent_model: .*growth rate 20 1/s.*settling_time = 20 s.*e\^400"):
        fxc_env.make_config(agent_model=unstable)
    # The same model over a horizon it can span runs (with a warning), and a slowly growing one over the default
    # horizon too.
    with pytest.warns(UnstableModelWarning):
        assert fxc_env.make_config(agent_model=unstable, settling_time=1.0).model.growth_rate == pytest.approx(20.0)
    with pytest.warns(UnstableModelWarning):
        slow = fxc_env.simulate(agent_model=([[0.2, 1.0], [0.0, 0.2]], [[0.0], [1.0]]), seed=0)
    assert slow.metrics.relative_deadline_error < 1e-6


def test_an_unstable_model_is_run_with_a_warning_naming_its_eigenvalues_and_refused_where_rounding_outgrows_agreement():
    import fxc_env
    from fxc_env.engine import ConsensusEngine
    from fxc_env.policies.reference import ReferencePolicy

    # e^(2.6 x 20) = 4e22: the exact reference would end at D(T_s)/D(0) far above 1 (0.35 to 2.7 already at 30).
    with pytest.raises(ArgumentError, match=r"^agent_model: A has unstable eigenvalue\(s\) 2.6 \(1/s\).*<= 30"):
        fxc_env.make_config(agent_model=([[0.0, 1.0], [0.0, 2.6]], [[0.0], [1.0]]))
    with pytest.warns(UnstableModelWarning, match=r"^agent_model: A has unstable eigenvalue\(s\) 1 \(1/s\).*e\^20"):
        config = fxc_env.make_config(agent_model=([[0.0, 1.0], [0.0, 1.0]], [[0.0], [1.0]]), schedule="uniform")
    # The episode finishes and reports what it can: no E* (its Gramian over T_s is singular in float64).
    policy, engine = ReferencePolicy(config), ConsensusEngine(config, n_episodes=2)
    engine.reset_from_draws([engine.draw_episode(np.random.default_rng(seed)) for seed in range(2)])
    while not engine.done:
        engine.step(np.asarray(policy(engine.observations()), dtype=np.float64))
    metrics = engine.batch_metrics()
    assert np.all(np.isnan(metrics["energy_bound"])) and np.all(metrics["relative_deadline_error"] < 1e-2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a stable or marginal model says nothing
        fxc_env.make_config(agent_model={"name": "damped"})
        fxc_env.make_config(agent_model={"name": "oscillator"})
