"""The engine's clock: lock step until a partial reset, then one instant per episode."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fxc_env import ConsensusEngine, make_config
from fxc_env.engine.backend import NumpyBackend
from fxc_env.engine.clock import EpisodeClock, InstantTables, LockStepClock


@pytest.mark.parametrize("schedule", ["paper", "uniform"])
def test_lock_step_intervals_add_up_to_the_deadline_exactly(schedule):
    config = make_config("paper_fig1", schedule=schedule, n_intervals=50)
    clock = LockStepClock(InstantTables(config, NumpyBackend("float64", 1)))
    played = []
    while not clock.done:
        start = clock.time
        played.append(clock.interval())
        clock.check_can_step()
        clock.advance()
        assert clock.time - start == pytest.approx(played[-1], rel=1e-12)
    assert clock.k == config.n_intervals
    assert clock.time == config.settling_time  # t_K = T_s exactly, the figure of merit's instant
    assert math.fsum(played) == pytest.approx(config.settling_time, rel=1e-14)
    with pytest.raises(RuntimeError, match="reached T_s"):
        clock.check_can_step()


def test_clock_features_are_time_interval_and_index_over_their_totals():
    config = make_config("paper_fig1", n_intervals=20)
    tables = InstantTables(config, NumpyBackend("float64", 1))
    clock = LockStepClock(tables, k=7)
    times, intervals = config.schedule.times, config.schedule.intervals
    np.testing.assert_allclose(clock.per_instant(tables.features), [times[7] / 20.0, intervals[7] / 20.0, 7 / 20])


def test_episode_clock_moves_each_episode_and_holds_at_the_deadline():
    config = make_config("paper_fig1", n_intervals=5)
    tables = InstantTables(config, NumpyBackend("float64", 3))
    clock = EpisodeClock(tables, np.array([0, 4, 5]), k=2)
    np.testing.assert_array_equal(clock.past_deadline(), [False, False, True])
    np.testing.assert_array_equal(clock.interval(2)[:, 0, 0], np.array(tables.next_interval)[[0, 4, 5]])
    assert clock.per_instant(tables.features).shape == (3, 1, 3)
    np.testing.assert_array_equal(clock.advance(), [1, 5, 5])
    with pytest.raises(RuntimeError, match="episode_done"):
        _ = clock.done


def test_partial_reset_gives_each_episode_its_own_clock():
    config = make_config("paper_fig1", n_intervals=10)
    engine = ConsensusEngine(config, n_episodes=3)
    x0, v0 = np.ones((3, 6, 1)) * np.arange(6)[:, None], np.zeros((3, 6, 1))
    engine.reset(x0, v0)
    for _ in range(4):
        engine.step(np.zeros((3, 6, 2)))
    assert engine.steps is None and engine.k == 4
    engine.reset(x0, v0, episodes=np.array([False, True, False]))
    np.testing.assert_array_equal(engine.steps, [4, 0, 4])
    engine.step(np.zeros((3, 6, 2)))
    np.testing.assert_array_equal(engine.steps, [5, 1, 5])
    np.testing.assert_array_equal(engine.episode_done(), [False, False, False])
