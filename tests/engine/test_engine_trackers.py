"""The episode trackers: rewards that telescope, totals, the initial state kept, and room for more metrics."""

from __future__ import annotations

import math

import numpy as np
from helpers import PAPER_V0, PAPER_X0

from fxc_env import ConsensusEngine, ReferencePolicy, make_config
from fxc_env.engine.trackers import EpisodeTrackers


def paper_episode(**kwargs):
    config = make_config("paper_fig1", **kwargs)
    engine = ConsensusEngine(config, n_episodes=2)
    engine.reset(np.stack([PAPER_X0, -PAPER_X0])[..., None], np.stack([PAPER_V0, PAPER_V0])[..., None])
    return config, engine


def test_rewards_telescope_and_energies_add_up():
    config, engine = paper_episode(n_intervals=40)
    policy = ReferencePolicy(config)
    rewards, energy = 0.0, 0.0
    while not engine.done:
        outcome = engine.step(policy(engine.observations()))
        rewards = rewards + outcome.reward
        energy = energy + outcome.energy.sum(axis=1)
    floor = engine.trackers.floor
    expected = np.log(engine.initial_disagreement + floor) - np.log(engine.current_disagreement + floor)
    np.testing.assert_allclose(rewards, expected, rtol=1e-9)
    np.testing.assert_allclose(engine.batch_metrics()["energy"], energy, rtol=1e-12)


def test_the_initial_state_is_kept_per_episode_through_a_partial_reset():
    _, engine = paper_episode(n_intervals=40)
    for _ in range(5):
        engine.step(np.zeros((2, 6, 2)))
    np.testing.assert_array_equal(engine.z0[:, :, 0, 0], [PAPER_X0, -PAPER_X0])
    engine.reset(np.zeros((2, 6, 1)), np.ones((2, 6, 1)), episodes=np.array([False, True]))
    np.testing.assert_array_equal(engine.z0[0, :, 0, 0], PAPER_X0)
    np.testing.assert_array_equal(engine.z0[1, :, :, 0], np.tile([0.0, 1.0], (6, 1)))
    assert engine.initial_disagreement[1] == 0.0 and engine.initial_disagreement[0] > 0


def test_settling_instants_are_the_last_above_each_threshold():
    config, engine = paper_episode(n_intervals=60)
    policy = ReferencePolicy(config)
    ratios = [1.0]
    while not engine.done:
        engine.step(policy(engine.observations()))
        ratios.append(float(engine.current_disagreement[0] / engine.initial_disagreement[0]))
    last = max(k for k, ratio in enumerate(ratios) if ratio >= 1e-2)
    times = np.concatenate([config.schedule.times, [math.inf]])
    assert engine.batch_metrics()["t_eps_1e_2"][0] == times[last + 1]


def test_extra_metrics_join_the_batch_metrics():
    class WithInitialSpread(EpisodeTrackers):
        def extra_metrics(self, state, steps):
            return {"initial_position_range": np.ptp(self.z0[:, :, 0, 0], axis=1)}

    _, engine = paper_episode()
    engine.trackers.__class__ = WithInitialSpread
    metrics = engine.batch_metrics()
    np.testing.assert_array_equal(metrics["initial_position_range"], [np.ptp(PAPER_X0), np.ptp(PAPER_X0)])
    assert "energy" in metrics
