"""Whole episodes: exactness against solve_ivp, Theorems 1-2, invariants, mode equivalence."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    MODES,
    PAPER_GRAPHS,
    PAPER_V0,
    PAPER_V_STAR,
    PAPER_X0,
    PAPER_X_STAR,
    PAPER_XI,
    averaging_matrix_by_hand,
    brute_spread,
    left_perron_vector,
    relative_error,
)
from scipy.integrate import solve_ivp

import fxc_env
from fxc_env import ReferencePolicy, make_topology, simulate
from fxc_env.core.validation import ArgumentError


def integrate_episode(trajectory):
    """Integrate x' = v, v' = u(t) with solve_ivp interval by interval (u affine on each,
    from the applied end values), chaining the numerical state; returns (K+1, N, dim) x, v."""
    shape = trajectory.x.shape[1:]
    n = int(np.prod(shape))
    y = np.concatenate([trajectory.x[0].ravel(), trajectory.v[0].ravel()])
    xs, vs = [trajectory.x[0]], [trajectory.v[0]]
    for k, T in enumerate(trajectory.config.schedule.intervals):
        u0, u1 = trajectory.u_start[k].ravel(), trajectory.u_end[k].ravel()

        def rhs(s, state, u0=u0, u1=u1, T=T):
            return np.concatenate([state[n:], u0 + (u1 - u0) * s / T])

        sol = solve_ivp(rhs, (0.0, T), y, method="DOP853", rtol=1e-12, atol=1e-14)
        assert sol.success
        y = sol.y[:, -1]
        xs.append(y[:n].reshape(shape))
        vs.append(y[n:].reshape(shape))
    return np.array(xs), np.array(vs)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"scenario": "paper_fig1"},
        {"scenario": "ring_6", "action_mode": "accel", "obs_mode": "raw"},
        {"scenario": "random_20_planar", "n_intervals": 60, "seed": 3},
        {"scenario": None, "topology": "random", "n_agents": 8, "schedule": "uniform", "n_intervals": 40},
    ],
)
def test_sampled_states_match_solve_ivp(kwargs):
    trajectory = simulate(**kwargs)
    xs, vs = integrate_episode(trajectory)
    for k in range(len(trajectory.times)):
        exact = np.concatenate([trajectory.x[k], trajectory.v[k]])
        numeric = np.concatenate([xs[k], vs[k]])
        assert np.linalg.norm(exact - numeric) <= 1e-9 * np.linalg.norm(numeric), k


def test_dense_trajectory_matches_solve_ivp_inside_intervals():
    trajectory = simulate(n_intervals=12, points_per_interval=8)
    shape = trajectory.x.shape[1:]
    n = int(np.prod(shape))
    for k in (0, 5, 11):
        T = trajectory.config.schedule.intervals[k]
        u0, u1 = trajectory.u_start[k].ravel(), trajectory.u_end[k].ravel()
        offsets = T * np.arange(8) / 8

        def rhs(s, state, u0=u0, u1=u1, T=T):
            return np.concatenate([state[n:], u0 + (u1 - u0) * s / T])

        y0 = np.concatenate([trajectory.x[k].ravel(), trajectory.v[k].ravel()])
        sol = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-12, atol=1e-14, t_eval=offsets)
        dense = slice(8 * k, 8 * k + 8)
        np.testing.assert_allclose(trajectory.dense_times[dense], trajectory.times[k] + offsets, rtol=1e-14)
        scale = np.max(np.abs(sol.y))
        assert np.max(np.abs(trajectory.dense_x[dense].reshape(8, -1) - sol.y[:n].T)) <= 1e-9 * scale
        assert np.max(np.abs(trajectory.dense_v[dense].reshape(8, -1) - sol.y[n:].T)) <= 1e-9 * scale
        expected_u = u0 + (u1 - u0) * offsets[:, None] / T
        np.testing.assert_allclose(trajectory.dense_u[dense].reshape(8, -1), expected_u, rtol=1e-12, atol=1e-12)


def test_trajectory_shapes_and_ends():
    trajectory = simulate("reference", "random_20_planar", n_intervals=30, points_per_interval=5)
    assert trajectory.x.shape == trajectory.v.shape == (31, 20, 2)
    assert trajectory.u_start.shape == trajectory.u_end.shape == (30, 20, 2)
    assert trajectory.dense_x.shape == (151, 20, 2) and trajectory.dense_times.shape == (151,)
    assert trajectory.times[-1] == trajectory.dense_times[-1] == 20.0
    np.testing.assert_array_equal(trajectory.dense_x[::5], trajectory.x)
    np.testing.assert_array_equal(trajectory.dense_v[::5], trajectory.v)
    for k in (0, 10, 30):
        expected = brute_spread(trajectory.x[k]) + 20.0 * brute_spread(trajectory.v[k])
        assert trajectory.disagreement[k] == pytest.approx(expected, rel=1e-12)


# --------------------------------------------------------------- Theorem 2


def test_theorem_2_on_the_paper_example():
    trajectory = simulate()  # paper_fig1, K = 200, reference policy
    ws = [averaging_matrix_by_hand(6, g) for g in PAPER_GRAPHS]
    xi = left_perron_vector(ws[2] @ ws[1] @ ws[0])
    np.testing.assert_allclose(xi, PAPER_XI, atol=1e-12)
    assert xi @ PAPER_X0 + 20.0 * xi @ PAPER_V0 == pytest.approx(PAPER_X_STAR, abs=1e-12)
    assert xi @ PAPER_V0 == pytest.approx(PAPER_V_STAR, abs=1e-12)
    np.testing.assert_allclose(trajectory.x[-1, :, 0], PAPER_X_STAR, rtol=0, atol=1e-9)
    np.testing.assert_allclose(trajectory.v[-1, :, 0], PAPER_V_STAR, rtol=0, atol=1e-9)
    m = trajectory.metrics
    assert m.achieved_final_position == pytest.approx(PAPER_X_STAR, abs=1e-9)
    assert m.achieved_final_velocity == pytest.approx(PAPER_V_STAR, abs=1e-9)
    assert m.relative_deadline_error <= 1e-9
    np.testing.assert_allclose(trajectory.config.topology.consensus_weights(), PAPER_XI, atol=1e-12)


def test_paper_example_invariant_over_each_period():
    # Over a whole period the product Pi acts, and xi^T Pi = xi^T: xi^T V is constant at t_{3p}.
    trajectory = simulate()
    at_period_starts = trajectory.v[::3, :, 0] @ PAPER_XI
    np.testing.assert_allclose(at_period_starts, PAPER_V_STAR, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
def test_paper_example_in_every_mode(action_mode, obs_mode):
    trajectory = simulate(action_mode=action_mode, obs_mode=obs_mode)
    np.testing.assert_allclose(trajectory.x[-1, :, 0], PAPER_X_STAR, rtol=0, atol=1e-9)
    np.testing.assert_allclose(trajectory.v[-1, :, 0], PAPER_V_STAR, rtol=0, atol=1e-9)


def test_anchors_of_the_paper_example():
    trajectory = simulate(points_per_interval=24)
    spreads = np.array([brute_spread(x) for x in trajectory.x])
    assert spreads[0] == 8.0
    assert 60.0 < spreads.max() < 100.0  # "grows from 8 to about 80 before it shrinks"
    assert trajectory.metrics.peak_input == pytest.approx(2.5e4, rel=0.05)
    assert trajectory.metrics.peak_input == max(np.abs(trajectory.u_start).max(), np.abs(trajectory.u_end).max())
    assert np.abs(trajectory.dense_u).max() <= trajectory.metrics.peak_input
    assert simulate(scenario="ring_6").metrics.peak_input == pytest.approx(1.3e4, rel=0.05)
    assert 1e-11 < simulate(n_intervals=201).metrics.final_position_spread < 1e-9  # "near 1e-10"
    assert simulate(n_intervals=402).metrics.final_position_spread <= 1e-14  # round-off


# --------------------------------------------------------------- Theorem 1


@pytest.mark.parametrize("n", [4, 7, 12, 30])
@pytest.mark.parametrize("seed", range(4))
def test_theorem_1_on_random_fixed_digraphs(n, seed):
    topology = make_topology("random", n, seed=seed)
    assert topology.period == 1
    w = averaging_matrix_by_hand(n, topology.edges[0])
    xi = left_perron_vector(w)
    np.testing.assert_allclose(topology.consensus_weights(), xi, atol=1e-10)
    trajectory = simulate(scenario=None, topology=topology, seed=seed, n_intervals=200)
    x0, v0 = trajectory.x[0, :, 0], trajectory.v[0, :, 0]
    x_star, v_star = xi @ x0 + 20.0 * xi @ v0, xi @ v0
    np.testing.assert_allclose(trajectory.x[-1, :, 0], x_star, rtol=0, atol=1e-8)
    np.testing.assert_allclose(trajectory.v[-1, :, 0], v_star, rtol=0, atol=1e-8)
    assert trajectory.x[-1, :, 0].mean() == pytest.approx(x_star, abs=1e-8)
    assert trajectory.v[-1, :, 0].mean() == pytest.approx(v_star, abs=1e-8)
    m = trajectory.metrics
    assert m.predicted_final_position == pytest.approx(x_star, abs=1e-10)
    assert m.predicted_final_velocity == pytest.approx(v_star, abs=1e-10)


@pytest.mark.parametrize("seed", range(3))
def test_invariants_along_a_fixed_graph_run(seed):
    # xi^T W = xi^T and the exact interval map give, at every sampling instant,
    # xi^T V(t_k) = xi^T V(0) and xi^T (X(t_k) - t_k V(t_k)) = xi^T X(0).
    topology = make_topology("random", 10, seed=seed)
    xi = left_perron_vector(averaging_matrix_by_hand(10, topology.edges[0]))
    trajectory = simulate(scenario=None, topology=topology, seed=seed, dim=2)
    times = trajectory.times[:, None, None]
    v_weighted = np.einsum("i,kid->kd", xi, trajectory.v)
    x_weighted = np.einsum("i,kid->kd", xi, trajectory.x - times * trajectory.v)
    scale = np.abs(trajectory.x).max() + 20.0 * np.abs(trajectory.v).max()
    assert np.max(np.abs(v_weighted - v_weighted[0])) <= 1e-12 * scale
    assert np.max(np.abs(x_weighted - x_weighted[0])) <= 1e-12 * scale


@pytest.mark.parametrize("seed", range(2))
def test_exact_interval_map_on_a_fixed_random_graph(seed):
    topology = make_topology("random", 9, seed=seed, mean_in_degree=3.0)
    w = averaging_matrix_by_hand(9, topology.edges[0])
    trajectory = simulate(scenario=None, topology=topology, seed=seed, n_intervals=80)
    for k, T in enumerate(trajectory.config.schedule.intervals):
        x, v = trajectory.x[k, :, 0], trajectory.v[k, :, 0]
        scale = np.abs(x).max() + T * np.abs(v).max()
        assert np.max(np.abs(trajectory.x[k + 1, :, 0] - (w @ x + T * w @ v))) <= 1e-12 * scale
        assert np.max(np.abs(trajectory.v[k + 1, :, 0] - w @ v)) <= 1e-12 * np.abs(v).max()


# ------------------------------------------------------- mode equivalence


@pytest.mark.parametrize("dim", [1, 2])
@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES[1:])
def test_reference_trajectory_is_the_same_in_every_mode(dim, action_mode, obs_mode):
    rng = np.random.default_rng(dim)
    x0, v0 = rng.uniform(-5, 5, size=(6, dim)), rng.uniform(-2, 2, size=(6, dim))
    base = simulate(scenario=None, x0=x0, v0=v0, dim=dim)  # plan, normalized
    other = simulate(scenario=None, x0=x0, v0=v0, dim=dim, action_mode=action_mode, obs_mode=obs_mode)
    assert relative_error(other.x, base.x) <= 1e-9
    assert relative_error(other.v, base.v) <= 1e-9
    assert relative_error(other.u_start, base.u_start) <= 1e-9
    assert relative_error(other.u_end, base.u_end) <= 1e-9


# ------------------------------------------------------------------ policies


def test_zero_policy_coasts():
    trajectory = simulate(lambda obs: np.zeros((*obs.shape[:-1], 2)), n_intervals=20)
    np.testing.assert_allclose(trajectory.x[-1, :, 0], PAPER_X0 + 20.0 * PAPER_V0, rtol=1e-14)
    np.testing.assert_array_equal(trajectory.v[-1, :, 0], PAPER_V0)
    assert trajectory.metrics.energy == 0.0


def test_policy_sees_only_observations():
    seen = []

    def policy(obs):
        seen.append(obs.copy())
        return np.zeros((*obs.shape[:-1], 2))

    trajectory = simulate(policy, n_intervals=7)
    assert len(seen) == 7
    assert all(obs.shape == (1, 6, trajectory.config.layout.size) for obs in seen)


def test_unknown_policy_name():
    with pytest.raises(ValueError, match="policy"):
        simulate("optimal")


def test_policy_output_is_validated():
    with pytest.raises(ValueError, match="policy output"):
        simulate(lambda obs: np.full((*obs.shape[:-1], 2), np.nan), n_intervals=3)


def test_explicit_initial_state_is_validated():
    with pytest.raises(ValueError, match="x0"):
        simulate(scenario=None, x0=np.zeros(5))
    with pytest.raises(ValueError, match="v0"):
        simulate(scenario=None, v0=np.full(6, np.inf))


def test_seed_draws_the_initial_state_when_the_scenario_has_none():
    a = simulate(scenario="random_20_planar", seed=1, n_intervals=5)
    b = simulate(scenario="random_20_planar", seed=1, n_intervals=5)
    c = simulate(scenario="random_20_planar", seed=2, n_intervals=5)
    np.testing.assert_array_equal(a.x, b.x)
    assert not np.array_equal(a.x[0], c.x[0])


# ------------------------------------------------------------------ seeding

#: Every source of randomness on: random initial state, switching graphs, noise and dropout.
NOISY = {
    "scenario": None,
    "topology": "random",
    "n_agents": 8,
    "topology_period": 3,
    "n_intervals": 30,
    "obs_noise": 0.1,
    "link_dropout": 0.3,
}


def parallel_env_episode(seed, **kwargs):
    """The ParallelEnv reset with ``seed`` and driven by the reference policy: states at each t_k."""
    env = fxc_env.parallel_env(**kwargs)
    policy = ReferencePolicy(env)
    observations, _ = env.reset(seed=seed)
    xs, vs = [env.engine.x[0].copy()], [env.engine.v[0].copy()]
    while env.agents:
        actions = policy(np.stack([observations[a] for a in env.possible_agents])[None])[0]
        observations, *_ = env.step(dict(zip(env.possible_agents, actions, strict=True)))
        xs.append(env.engine.x[0].copy())
        vs.append(env.engine.v[0].copy())
    return np.array(xs), np.array(vs), env.engine.episode_metrics(0)


def test_seed_fixes_noise_dropout_and_switching_too():
    a, b = simulate(seed=7, **NOISY), simulate(seed=7, **NOISY)
    for name in ("x", "v", "u_start", "u_end", "dense_x"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.metrics.as_dict() == b.metrics.as_dict()
    other = simulate(seed=8, **NOISY)
    assert not np.array_equal(a.x, other.x)


def test_noise_is_seeded_even_from_a_fixed_initial_state():
    # paper_fig1 fixes x0, v0: the seed only drives the noise, and still fixes the run.
    a, b = simulate(seed=0, obs_noise=0.1, n_intervals=20), simulate(seed=0, obs_noise=0.1, n_intervals=20)
    np.testing.assert_array_equal(a.x, b.x)
    c = simulate(seed=1, obs_noise=0.1, n_intervals=20)
    np.testing.assert_array_equal(a.x[0], c.x[0])
    assert not np.array_equal(a.x[-1], c.x[-1])


@pytest.mark.parametrize("seed", [0, 5])
def test_simulate_equals_the_parallel_env_reset_with_the_same_seed(seed):
    trajectory = simulate(seed=seed, **NOISY)
    xs, vs, metrics = parallel_env_episode(seed, **NOISY)
    np.testing.assert_array_equal(trajectory.x, xs)
    np.testing.assert_array_equal(trajectory.v, vs)
    assert trajectory.metrics.as_dict() == metrics.as_dict()


def test_bad_seed_and_points_per_interval_are_argument_errors():
    with pytest.raises(ArgumentError, match="seed"):
        simulate(seed=-1, n_intervals=5)
    with pytest.raises(ArgumentError, match="seed"):
        simulate(seed=1.5, n_intervals=5)
    with pytest.raises(ArgumentError, match="points_per_interval"):
        simulate(points_per_interval=0, n_intervals=5)


def test_an_out_of_range_deadline_names_settling_time_not_the_policy():
    with pytest.raises(ArgumentError, match=r"^settling_time: .*<= 1e\+30"):
        simulate(settling_time=1e300)
