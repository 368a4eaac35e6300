"""Realism options of the engine (docs: realism.md, "Realism options"): saturation, noise, dropout, random switching, long horizons."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import fxc_env
from fxc_env import ReferencePolicy, make_config
from fxc_env.engine import ConsensusEngine


def crossing_times(u0: float, u1: float, T: float, u_max: float) -> list[float]:
    """Where the commanded line crosses ±u_max strictly inside (0, T), found independently."""
    if u1 == u0:
        return []
    return sorted(s for s in ((level - u0) * T / (u1 - u0) for level in (-u_max, u_max)) if 0 < s < T)


def test_u_max_100_on_paper_fig1_caps_every_input_and_matches_solve_ivp():
    """Saturated at u_max = 100: |u| <= 100 everywhere and the state equals solve_ivp's to 1e-8 relative."""
    u_max = 100.0
    trajectory = fxc_env.simulate(scenario="paper_fig1", u_max=u_max)
    assert np.abs(trajectory.dense_u).max() <= u_max
    assert trajectory.metrics.peak_input <= u_max
    assert 0 < trajectory.metrics.saturated_fraction < 1  # the limit does bind
    # Integrate every agent on its own from the same start, splitting each interval where
    # its clipped input has a kink, with the input read from the commanded line.
    times = trajectory.times
    for agent in range(6):
        state = np.array([trajectory.x[0, agent, 0], trajectory.v[0, agent, 0]])
        for k in range(len(times) - 1):
            t0, t1 = times[k], times[k + 1]
            u0, u1 = trajectory.u_start[k, agent, 0], trajectory.u_end[k, agent, 0]
            T = t1 - t0
            edges = [0.0, *crossing_times(u0, u1, T, u_max), T]
            for a, b in itertools.pairwise(edges):

                def field(s, y, u0=u0, u1=u1, T=T):
                    return [y[1], np.clip(u0 + (u1 - u0) * s / T, -u_max, u_max)]

                state = solve_ivp(field, (a, b), state, rtol=1e-12, atol=1e-14).y[:, -1]
            scale = 1.0 + np.abs(trajectory.x[k + 1]).max()
            assert abs(state[0] - trajectory.x[k + 1, agent, 0]) <= 1e-8 * scale
            assert abs(state[1] - trajectory.v[k + 1, agent, 0]) <= 1e-8 * (1.0 + np.abs(trajectory.v[k + 1]).max())
            state = np.array([trajectory.x[k + 1, agent, 0], trajectory.v[k + 1, agent, 0]])


def test_a_limit_that_never_binds_changes_nothing():
    free = fxc_env.simulate(scenario="paper_fig1")
    loose = fxc_env.simulate(scenario="paper_fig1", u_max=10 * free.metrics.peak_input)
    np.testing.assert_allclose(loose.x, free.x, rtol=0, atol=1e-12 * np.abs(free.x).max())
    assert loose.metrics.saturated_fraction == 0.0


def test_saturation_is_reported_per_agent_in_infos():
    env = fxc_env.parallel_env(scenario="paper_fig1", u_max=1.0)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    fractions = []
    while env.agents:
        obs, _, _, _, infos = env.step({a: policy(o) for a, o in obs.items()})
        fractions += [info["saturated_fraction"] for info in infos.values()]
        assert all(info["peak_u"] <= 1.0 for info in infos.values())
    assert all(0.0 <= f <= 1.0 for f in fractions) and max(fractions) > 0.5
    assert 0 < infos["agent_0"]["episode"]["saturated_fraction"] <= 1


def _episode(seed, **kwargs):
    env = fxc_env.parallel_env(scenario="random_20_planar", **kwargs)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=seed)
    seen = []
    while env.agents:
        seen.append(np.stack([obs[a] for a in env.agents]))
        obs, *_ = env.step({a: policy(o) for a, o in obs.items()})
    return np.array(seen), env.state()


@pytest.mark.parametrize("kwargs", [{"obs_noise": 0.05}, {"link_dropout": 0.3}, {"switching": "random"}])
def test_random_options_are_seeded_whole_episodes(kwargs):
    first, second, other = _episode(3, **kwargs), _episode(3, **kwargs), _episode(4, **kwargs)
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])
    assert not np.array_equal(first[0], other[0])


def test_noise_perturbs_only_received_rows():
    config = make_config("random_20_planar", obs_noise=0.1, obs_mode="raw", obs_slots=5)
    engine = ConsensusEngine(config, n_episodes=4)
    engine.reset(np.zeros((4, 20, 2)), np.zeros((4, 20, 2)), rng=np.random.default_rng(0))
    rows, mask, _ = engine.layout.split(engine.observations())
    received = mask.astype(bool)
    # Agents agree exactly, so every nonzero row entry is noise, and only received rows carry it.
    assert np.all(rows[~received] == 0)
    assert np.std(rows[received]) == pytest.approx(0.1, rel=0.1)
    # Asking again at the same instant returns the same measurement.
    np.testing.assert_array_equal(engine.observations(), engine.observations())


def test_dropout_hides_lost_links_in_the_mask_and_the_rows():
    config = make_config(topology="complete", n_agents=8, link_dropout=0.5, obs_mode="raw")
    engine = ConsensusEngine(config, n_episodes=50)
    rng = np.random.default_rng(1)
    engine.reset(rng.normal(size=(50, 8, 1)), rng.normal(size=(50, 8, 1)), rng=rng)
    rows, mask, _ = engine.layout.split(engine.observations())
    assert set(np.unique(mask)) == {0.0, 1.0}
    assert mask.mean() == pytest.approx(0.5, abs=0.05)
    assert np.all(rows[mask == 0] == 0) and np.all(rows[mask == 1][..., 0, 0] != 0)


def test_random_switching_draws_each_episode_s_graph_from_the_set():
    config = make_config("paper_fig1", switching="random")
    engine = ConsensusEngine(config, n_episodes=200)
    engine.reset(np.zeros((200, 6, 1)), np.zeros((200, 6, 1)), rng=np.random.default_rng(2))
    drawn = engine.graph_indices()
    assert set(drawn) == {0, 1, 2}
    # The mask shows exactly the in-edges of each episode's drawn graph.
    _, mask, _ = engine.layout.split(engine.observations())
    in_degree = config.topology.in_degree
    np.testing.assert_array_equal(mask.sum(axis=-1), in_degree[drawn])
    engine.step(np.zeros((200, 6, 2)))
    assert not np.array_equal(engine.graph_indices(), drawn)
    assert np.isnan(engine.batch_metrics()["predicted_final_position"]).all()  # Theorem 2 needs a period


@pytest.mark.slow
def test_hundred_thousand_intervals_keep_the_final_value_without_overflow():
    """A long horizon: K = 1e5 on the paper example, no overflow, NaN or loss of x*(20) = -1.875."""
    config = make_config("paper_fig1", n_intervals=100_000)
    engine = ConsensusEngine(config)
    x0, v0 = engine.sample_initial_state(np.random.default_rng(0))
    engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(config)
    buffer = np.empty((1, 6, config.layout.size))
    with np.errstate(all="raise"):
        while not engine.done:
            engine.step(policy(engine.observations(buffer)))
    metrics = engine.episode_metrics()
    assert np.isfinite(engine.state).all() and np.isfinite(metrics.energy)
    assert abs(metrics.achieved_final_position - (-1.875)) <= 1e-9
    assert abs(metrics.achieved_final_velocity - (-0.125)) <= 1e-9
    assert metrics.relative_deadline_error <= 1e-12
