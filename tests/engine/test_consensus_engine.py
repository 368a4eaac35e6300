"""The batched engine: observations, actions, exact steps, rewards and episode metrics."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import (
    MODES,
    PAPER_GRAPHS,
    PAPER_V0,
    PAPER_X0,
    PAPER_XI,
    averaging_matrix_by_hand,
    brute_spread,
)

import fxc_env
from fxc_env import ConsensusEngine, ReferencePolicy, make_config
from fxc_env.core.dynamics import interval_energy


def paper_engine(**kwargs):
    config = make_config("paper_fig1", **kwargs)
    engine = ConsensusEngine(config)
    engine.reset(PAPER_X0[None, :, None], PAPER_V0[None, :, None])
    return config, engine


def reference_step(engine, policy):
    actions = engine.validate_actions(policy(engine.observations()))
    return engine.step(actions)


def test_reset_sets_the_state_and_clock():
    config, engine = paper_engine()
    assert engine.k == 0 and engine.time == 0.0 and not engine.done
    np.testing.assert_array_equal(engine.x[0, :, 0], PAPER_X0)
    np.testing.assert_array_equal(engine.v[0, :, 0], PAPER_V0)
    assert engine.current_interval() == config.schedule.intervals[0]


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
def test_reference_realises_the_exact_interval_map(action_mode, obs_mode):
    # The paper's interval map (17a): X(t_{k+1}) = W X(t_k) + T W V(t_k), V(t_{k+1}) = W V(t_k), with W of G_{k mod 3}.
    config, engine = paper_engine(action_mode=action_mode, obs_mode=obs_mode, n_intervals=60)
    policy = ReferencePolicy(config)
    ws = [averaging_matrix_by_hand(6, g) for g in PAPER_GRAPHS]
    for k in range(config.n_intervals):
        x, v = engine.x[0].copy(), engine.v[0].copy()
        T = config.schedule.intervals[k]
        w = ws[k % 3]
        reference_step(engine, policy)
        scale = np.max(np.abs(x)) + T * np.max(np.abs(v))
        assert np.max(np.abs(engine.x[0] - (w @ x + T * w @ v))) <= 1e-12 * scale, k
        assert np.max(np.abs(engine.v[0] - w @ v)) <= 1e-12 * np.max(np.abs(v)), k


def test_reference_inputs_are_eq_11_endpoints():
    config, engine = paper_engine(n_intervals=30)
    policy = ReferencePolicy(config)
    ws = [averaging_matrix_by_hand(6, g) for g in PAPER_GRAPHS]
    for k in range(config.n_intervals):
        x, v = engine.x[0, :, 0].copy(), engine.v[0, :, 0].copy()
        T = config.schedule.intervals[k]
        # e_x,i = (1/(d_i+1)) sum_j (x_i - x_j) = x_i - (W x)_i
        w = ws[k % 3]
        e_x, e_v = x - w @ x, v - w @ v
        outcome = reference_step(engine, policy)
        u0, u1 = outcome.u_start[0, :, 0], outcome.u_end[0, :, 0]
        expected_u0 = -6 * e_x / T**2 - 4 * e_v / T
        expected_u1 = 6 * e_x / T**2 + 2 * e_v / T
        tol = 1e-10 * max(np.max(np.abs(expected_u0)), 1e-300)
        np.testing.assert_allclose(u0, expected_u0, rtol=0, atol=tol)
        np.testing.assert_allclose(u1, expected_u1, rtol=0, atol=tol)
        np.testing.assert_allclose(
            outcome.energy[0], 12 * e_x**2 / T**3 + 12 * e_x * e_v / T**2 + 4 * e_v**2 / T, rtol=1e-9, atol=1e-12
        )
        np.testing.assert_allclose(outcome.peak_input[0], np.maximum(np.abs(u0), np.abs(u1)), rtol=1e-15)


def test_raw_observation_rows_mask_and_clock():
    config = make_config("random_20_planar", obs_mode="raw", n_intervals=20)
    engine = ConsensusEngine(config)
    x0, v0 = engine.sample_initial_state(np.random.default_rng(3))
    engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(config)
    layout, topo, sched = config.layout, config.topology, config.schedule
    for k in range(4):
        obs = engine.observations()[0]
        assert obs.shape == (20, layout.size)
        rows, mask, clock = layout.split(obs)
        edges = topo.edges[k % topo.period]
        for i in range(20):
            senders = sorted(int(j) for j, r in edges if r == i)
            d = len(senders)
            np.testing.assert_array_equal(mask[i], [1.0] * d + [0.0] * (layout.slots - d))
            for r, j in enumerate(senders):
                np.testing.assert_allclose(rows[i, r, 0], engine.x[0, j] - engine.x[0, i], rtol=1e-15)
                np.testing.assert_allclose(rows[i, r, 1], engine.v[0, j] - engine.v[0, i], rtol=1e-15)
            assert np.all(rows[i, d:] == 0.0)
        np.testing.assert_allclose(clock, [[sched.times[k] / 20.0, sched.intervals[k] / 20.0, k / 20]] * 20)
        reference_step(engine, policy)


def test_normalized_observation_is_raw_divided_by_the_local_scale():
    raw_c = make_config(obs_mode="raw", topology="random", n_agents=12, mean_in_degree=3.0)
    norm_c = make_config(obs_mode="normalized", topology="random", n_agents=12, mean_in_degree=3.0)
    rng = np.random.default_rng(0)
    x0, v0 = rng.normal(size=(1, 12, 1)), rng.normal(size=(1, 12, 1))
    raw_e, norm_e = ConsensusEngine(raw_c), ConsensusEngine(norm_c)
    raw_e.reset(x0, v0)
    norm_e.reset(x0, v0)
    T = raw_c.schedule.intervals[0]
    raw_rows, _, _ = raw_c.layout.split(raw_e.observations()[0])
    norm_rows, _, _ = norm_c.layout.split(norm_e.observations()[0])
    for i in range(12):
        scale = max(np.max(np.abs(raw_rows[i, :, 0])), T * np.max(np.abs(raw_rows[i, :, 1])))
        assert scale > 0
        np.testing.assert_allclose(norm_rows[i, :, 0], raw_rows[i, :, 0] / scale, rtol=1e-14, atol=1e-16)
        np.testing.assert_allclose(norm_rows[i, :, 1], T * raw_rows[i, :, 1] / scale, rtol=1e-14, atol=1e-16)
        assert np.max(np.abs(norm_rows[i])) == pytest.approx(1.0, rel=1e-15)
    assert np.max(np.abs(norm_rows)) <= 1.0


def test_batch_equals_independent_single_episodes():
    config = make_config("random_20_planar", n_intervals=25)
    rng = np.random.default_rng(4)
    x0 = rng.uniform(-5, 5, size=(3, 20, 2))
    v0 = rng.uniform(-2, 2, size=(3, 20, 2))
    batch = ConsensusEngine(config, n_episodes=3)
    batch.reset(x0, v0)
    singles = [ConsensusEngine(config) for _ in range(3)]
    for b, engine in enumerate(singles):
        engine.reset(x0[b : b + 1], v0[b : b + 1])
    policy = ReferencePolicy(config)
    while not batch.done:
        out = reference_step(batch, policy)
        for b, engine in enumerate(singles):
            one = reference_step(engine, policy)
            np.testing.assert_allclose(batch.x[b], engine.x[0], rtol=1e-13, atol=1e-13)
            np.testing.assert_allclose(batch.v[b], engine.v[0], rtol=1e-13, atol=1e-13)
            assert out.reward[b] == pytest.approx(one.reward[0], rel=1e-9, abs=1e-12)
    assert all(engine.done for engine in singles)


def test_reward_telescopes_to_the_log_reduction():
    config, engine = paper_engine()
    policy = ReferencePolicy(config)
    d0 = brute_spread(PAPER_X0) + 20.0 * brute_spread(PAPER_V0)
    floor = 1e-12 * d0
    total = 0.0
    while not engine.done:
        x, v = engine.x[0].copy(), engine.v[0].copy()
        reward = reference_step(engine, policy).reward[0]
        before = brute_spread(x) + 20.0 * brute_spread(v)
        after = brute_spread(engine.x[0]) + 20.0 * brute_spread(engine.v[0])
        assert reward == pytest.approx(np.log(before + floor) - np.log(after + floor), rel=1e-9, abs=1e-12)
        total += reward
    d_end = brute_spread(engine.x[0]) + 20.0 * brute_spread(engine.v[0])
    assert total == pytest.approx(np.log(d0 + floor) - np.log(d_end + floor), rel=1e-9)


def test_episode_metrics_match_their_definitions():
    config, engine = paper_engine()
    policy = ReferencePolicy(config)
    energies, peaks, ratios = [], [], [1.0]
    d0 = brute_spread(PAPER_X0) + 20.0 * brute_spread(PAPER_V0)
    while not engine.done:
        out = reference_step(engine, policy)
        T = config.schedule.intervals[engine.k - 1]
        np.testing.assert_allclose(out.energy[0], interval_energy(out.u_start[0], out.u_end[0], T), rtol=1e-15)
        energies.append(out.energy[0].sum())
        peaks.append(out.peak_input[0].max())
        ratios.append((brute_spread(engine.x[0]) + 20.0 * brute_spread(engine.v[0])) / d0)
    assert out.terminated
    m = engine.episode_metrics()
    times = config.schedule.times
    assert m.sampling_instants == config.n_intervals == 200
    assert m.energy == pytest.approx(sum(energies), rel=1e-12)
    assert m.peak_input == max(peaks)
    assert m.relative_deadline_error == pytest.approx(ratios[-1], rel=1e-9)
    assert m.final_position_spread == pytest.approx(brute_spread(engine.x[0]), rel=1e-12)
    assert m.final_velocity_spread == pytest.approx(brute_spread(engine.v[0]), rel=1e-12)
    for eps, t_eps in ((1e-2, m.t_eps_1e_2), (1e-6, m.t_eps_1e_6)):
        # First sampling instant from which D(t_k)/D(0) < eps at every later instant.
        first = min(k for k in range(len(ratios)) if all(r < eps for r in ratios[k:]))
        assert t_eps == times[first]
    assert m.predicted_final_position == pytest.approx(PAPER_XI @ PAPER_X0 + 20.0 * PAPER_XI @ PAPER_V0, abs=1e-12)
    assert m.predicted_final_velocity == pytest.approx(PAPER_XI @ PAPER_V0, abs=1e-12)
    assert m.achieved_final_position == pytest.approx(engine.x[0, :, 0].mean(), rel=1e-15)
    assert m.achieved_final_velocity == pytest.approx(engine.v[0, :, 0].mean(), rel=1e-15)


def test_t_eps_is_infinite_when_the_threshold_is_never_reached():
    config = make_config("paper_fig1", n_intervals=5)
    engine = ConsensusEngine(config)
    engine.reset(PAPER_X0[None, :, None], PAPER_V0[None, :, None])
    zeros = np.zeros((1, 6, 2))
    while not engine.done:
        engine.step(zeros)  # coasting never agrees
    assert engine.episode_metrics().t_eps_1e_6 == np.inf


def test_step_after_the_deadline_raises():
    config, engine = paper_engine(n_intervals=3)
    policy = ReferencePolicy(config)
    for _ in range(3):
        reference_step(engine, policy)
    assert engine.done and engine.time == 20.0
    with pytest.raises(RuntimeError, match="step"):
        engine.step(np.zeros((1, 6, 2)))


@pytest.mark.parametrize(
    ("actions", "error"),
    [
        (np.zeros((1, 6, 3)), ValueError),
        (np.zeros((6, 2)), ValueError),
        (np.full((1, 6, 2), np.nan), ValueError),
        (np.full((1, 6, 2), np.inf), ValueError),
        (np.full((1, 6, 2), "a"), TypeError),
    ],
)
def test_validate_actions_names_the_argument(actions, error):
    _, engine = paper_engine()
    with pytest.raises(error, match="my_actions"):
        engine.validate_actions(actions, name="my_actions")


@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
def test_zero_action_coasts(action_mode, obs_mode):
    _, engine = paper_engine(action_mode=action_mode, obs_mode=obs_mode, n_intervals=10)
    while not engine.done:
        out = engine.step(np.zeros((1, 6, 2)))
        assert np.all(out.energy == 0.0)
    np.testing.assert_allclose(engine.x[0, :, 0], PAPER_X0 + 20.0 * PAPER_V0, rtol=1e-14)
    np.testing.assert_array_equal(engine.v[0, :, 0], PAPER_V0)


def test_padding_slots_changes_nothing_but_the_observation_width():
    """obs_slots adds zero rows with mask 0: the reference's trajectory is unchanged."""
    base = fxc_env.simulate(scenario="random_20_planar")
    padded = fxc_env.simulate(scenario="random_20_planar", obs_slots=base.config.layout.slots + 3)
    assert padded.config.layout.size == base.config.layout.size + 3 * (2 * 2 + 1)
    np.testing.assert_allclose(padded.x, base.x, rtol=0, atol=1e-12 * np.abs(base.x).max())


def test_index_gathers_agree_with_the_sparse_and_dense_averaging_matrices_at_scale():
    """The engine's neighbour gathers realise X <- W X + T W V, with W built sparse (scipy) and dense."""
    config = make_config(topology="random", n_agents=3000, mean_in_degree=3.5, topology_period=2, n_intervals=50)
    engine = ConsensusEngine(config)
    x0, v0 = engine.sample_initial_state(np.random.default_rng(4))
    engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(config)
    x_sparse, v_sparse = x0.copy(), v0.copy()
    x_dense, v_dense = x0.copy(), v0.copy()
    for k in range(6):
        T = config.schedule.intervals[k]
        w = config.topology.averaging_matrix(k % 2)  # scipy.sparse, O(|E|)
        x_sparse, v_sparse = w @ (x_sparse + T * v_sparse), w @ v_sparse
        dense = w.toarray()
        x_dense, v_dense = dense @ (x_dense + T * v_dense), dense @ v_dense
        engine.step(policy(engine.observations()))
    scale = np.abs(x0).max()
    np.testing.assert_allclose(x_sparse, x_dense, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(engine.x[0], x_sparse, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(engine.v[0], v_sparse, rtol=0, atol=1e-9 * scale)
