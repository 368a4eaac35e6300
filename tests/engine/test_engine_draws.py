"""Episode draws: seeds keep their episodes, and one batched reset from per-episode draws."""

from __future__ import annotations

import numpy as np

from fxc_env import ConsensusEngine, make_config
from fxc_env.engine import draws


def test_a_seed_keeps_its_episode_and_the_draws_stay_in_their_ranges():
    config = make_config("random_20_planar", position_range=3.0, velocity_range=0.5)
    first = draws.draw_episode(config, np.random.default_rng(11))
    second = draws.draw_episode(config, np.random.default_rng(11))
    np.testing.assert_array_equal(first.x0, second.x0)
    np.testing.assert_array_equal(first.v0, second.v0)
    assert first.x0.shape == (20, 2) and np.abs(first.x0).max() <= 3.0 and np.abs(first.v0).max() <= 0.5


def test_reset_from_draws_is_the_batched_reset_of_the_stacked_draws():
    config = make_config("paper_fig1", u_max=(10.0, 100.0), initial_state="random")
    rng = np.random.default_rng(5)
    episode_draws = [draws.draw_episode(config, rng) for _ in range(4)]
    one, other = ConsensusEngine(config, 4), ConsensusEngine(config, 4)
    one.reset_from_draws(episode_draws)
    batch = draws.stack_draws(episode_draws, config)
    other.reset(batch.x0, batch.v0, u_max=batch.u_max)
    np.testing.assert_array_equal(one.state, other.state)
    np.testing.assert_array_equal(one.u_max, [d.u_max for d in episode_draws])
    assert batch.x0.shape == (4, 6, 1) and batch.topologies is None


def test_batched_draws_follow_the_configs_ranges_and_limits():
    config = make_config("paper_fig1", u_max=(10.0, 100.0, 1000.0), position_range=(0.1, 10.0), initial_state="random")
    engine = ConsensusEngine(config, 256)
    engine.seed(0)
    x0, v0, u_max, topologies = engine.draw_batch()
    assert x0.shape == (256, 6, 1) and topologies is None
    assert np.abs(x0).max() <= 10.0 and np.abs(v0).max() <= 2.0
    widths = np.abs(x0).max(axis=(1, 2))
    assert widths.min() < 1.0 < widths.max()  # log-uniform half-widths span the decades
    assert set(np.unique(u_max)) <= {10.0, 100.0, 1000.0}
