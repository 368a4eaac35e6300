"""Measurements and observations: the numpy fast path gives the generic path's values bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env import ConsensusEngine, make_config
from fxc_env.engine import observations
from fxc_env.engine.observations import limit_feature


def engine_at(n_agents, seed=0, **kwargs):
    config = make_config(topology="random", n_agents=n_agents, mean_in_degree=3.0, n_intervals=12, **kwargs)
    engine = ConsensusEngine(config, n_episodes=2)
    rng = np.random.default_rng(seed)
    x0, v0 = rng.normal(size=(2, n_agents, config.dim)), rng.normal(size=(2, n_agents, config.dim))
    engine.reset(x0, v0)
    for _ in range(3):
        engine.step(np.zeros((2, n_agents, config.action_size)))
    return engine


@pytest.mark.parametrize("dim", [1, 2])
@pytest.mark.parametrize("obs_mode", ["normalized", "raw"])
def test_the_blocked_observation_equals_the_generic_one_bit_for_bit(monkeypatch, dim, obs_mode):
    monkeypatch.setattr(observations, "BLOCK_AGENTS", 1000)  # several blocks and a short last one
    engine = engine_at(4321, dim=dim, obs_mode=obs_mode)
    assert engine.observer.blocked and engine.graphs.same_graph
    fast = engine.observations(np.empty((2, 4321, engine.layout.size))).copy()
    fast_scale = engine.local_scale().copy()
    engine.observer.invalidate()
    engine.observer.blocked = False
    generic = engine.observations()
    np.testing.assert_array_equal(fast, generic)
    np.testing.assert_array_equal(fast_scale, engine.local_scale())


def test_the_local_scale_is_the_largest_relative_position_or_T_times_velocity():
    engine = engine_at(40, dim=2)
    _, _, scale = engine.measurements()
    T = engine.current_interval()
    x, v = engine.x[1], engine.v[1]
    index = engine.graphs.neighbour_index[engine.graphs.graph]
    for i in range(40):
        neighbours = index[i][engine.graphs.mask_features[engine.graphs.graph][i] > 0]
        expected = max(np.abs(x[neighbours] - x[i]).max(initial=0.0), T * np.abs(v[neighbours] - v[i]).max(initial=0.0))
        assert scale[1, i] == expected


def test_measurements_are_drawn_once_per_instant():
    config = make_config("paper_fig1", obs_noise=0.1)
    engine = ConsensusEngine(config)
    engine.reset(np.ones((1, 6, 1)), np.zeros((1, 6, 1)))
    first = engine.observations()
    np.testing.assert_array_equal(engine.observations(), first)  # cached: the same noise
    engine.step(np.zeros((1, 6, 2)))
    assert not np.array_equal(engine.observations()[..., :4], first[..., :4])


def test_the_limit_feature_spreads_decades_evenly():
    scale = np.array([1.0, 10.0, 0.1, 0.0])
    np.testing.assert_allclose(limit_feature(1.0, 1.0, scale), [0.0, -0.5, 0.5, 1.0])


def test_an_engine_on_the_fast_path_pickles_mid_episode_and_continues_bit_for_bit():
    import pickle

    engine = engine_at(5000)
    engine.observations(np.empty((2, 5000, engine.layout.size)))  # the fast path's buffers exist
    twin = pickle.loads(pickle.dumps(engine))
    for _ in range(4):
        actions = np.tanh(engine.observations()[..., :2])
        engine.step(actions)
        twin.step(np.tanh(twin.observations()[..., :2]))
    np.testing.assert_array_equal(twin.state, engine.state)
    np.testing.assert_array_equal(twin.observations(), engine.observations())
