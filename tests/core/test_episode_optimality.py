"""The optimality columns of every episode's metrics: E*, energy / E*, the settled interval, the intervals bounds.

They come from the engine's trackers, so every front end reports the same numbers: the
PettingZoo infos, the SB3 VecEnv infos, the TorchRL env's episode metrics and ``simulate``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import fxc_env
from fxc_env.core.metrics import SETTLED_TOLERANCE
from fxc_env.core.optimality import energy_bound, settled_interval
from fxc_env.engine import ConsensusEngine

#: The paper's example (Section 5): E* = 5.4597 m²/s³ at T_s = 20 s.
PAPER_X0 = np.array([1.0, -1.0, 2.0, 4.0, -4.0, -2.0])
PAPER_V0 = np.array([1.0, 2.0, 3.0, -3.0, -2.0, 0.0])


def play_reference(env):
    """One reference episode of a PettingZoo parallel env; the last step's infos."""
    policy = fxc_env.ReferencePolicy(env)
    observations, infos = env.reset(seed=0)
    while env.agents:
        observations, _, _, _, infos = env.step({a: policy(o) for a, o in observations.items()})
    return infos


def test_the_paper_example_reports_e_star_and_the_reference_s_distance_from_it():
    trajectory = fxc_env.simulate(scenario="paper_fig1")
    m = trajectory.metrics
    closed_form = energy_bound(PAPER_X0[:, None], PAPER_V0[:, None], 20.0)
    assert m.energy_bound == pytest.approx(float(closed_form), rel=1e-12)
    assert m.energy_bound == pytest.approx(5.4597, abs=5e-5)
    assert m.energy_ratio == pytest.approx(m.energy / m.energy_bound, rel=1e-12)
    assert 1e7 < m.energy_ratio < 3e7  # the reference spends 1.7e7 x E* on the paper's schedule
    # The assumed Fig. 1 switching ring, through the time-varying graph: agent 0 reaches everyone after
    # 5 intervals (any law's bound), the last root heard everywhere after 7 (the reference's: xi > 0 on all).
    assert (m.radius_bound, m.all_roots_bound, m.propagation_bound) == (5, 7, 7)
    assert m.all_roots_bound <= m.settled_interval <= 200
    assert m.energy >= m.energy_bound


def test_the_settled_interval_is_the_one_after_which_the_error_stayed_below_1e_9():
    config = fxc_env.make_config(scenario=None, topology="ring", n_agents=6)
    engine = ConsensusEngine(config, n_episodes=3)
    rng = np.random.default_rng(4)
    engine.reset(rng.uniform(-5, 5, (3, 6, 1)), rng.uniform(-2, 2, (3, 6, 1)))
    policy = fxc_env.ReferencePolicy(config)
    trace = [np.ones(3)]
    d0 = engine.initial_disagreement.copy()
    while not engine.done:
        engine.step(policy(engine.observations()))
        trace.append(engine.current_disagreement / d0)
    metrics = engine.batch_metrics()
    expected = settled_interval(np.array(trace).T, SETTLED_TOLERANCE)
    assert np.array_equal(metrics["settled_interval"], expected)
    assert np.all(np.isfinite(expected)) and np.all(metrics["propagation_bound"] == 5)  # a ring of 6: N - 1


def test_every_front_end_reports_the_same_bounds():
    kwargs = {"scenario": None, "topology": "ring", "n_agents": 6, "n_intervals": 50}
    infos = play_reference(fxc_env.parallel_env(**kwargs))
    episode = infos["agent_0"]["episode"]
    env = fxc_env.parallel_env(**kwargs)
    env.reset(seed=0)
    x0, v0 = env.engine.x0[0], env.engine.v0[0]
    assert episode["energy_bound"] == pytest.approx(float(energy_bound(x0, v0, 20.0)), rel=1e-12)
    assert episode["propagation_bound"] == 5
    assert episode["energy_ratio"] == pytest.approx(episode["energy"] / episode["energy_bound"], rel=1e-12)

    from fxc_env.envs.vec_env import ConsensusVecEnv

    vec = ConsensusVecEnv(1, **kwargs)
    vec.seed(0)
    vec.reset()
    policy = fxc_env.ReferencePolicy(vec.config)
    done = np.zeros(6, dtype=bool)
    observations = vec.reset()
    while not done.any():
        observations, _, done, vec_infos = vec.step(policy(observations))
    vec_episode = vec_infos[0]["episode_metrics"]
    assert vec_episode["settled_interval"] == math.inf  # K = 50 leaves the ring of 6 at about 1e-3
    assert vec_episode["propagation_bound"] == 5 and vec_episode["energy_bound"] > 0
    assert vec_episode["energy_ratio"] == pytest.approx(vec_episode["energy"] / vec_episode["energy_bound"], rel=1e-12)


def test_random_switching_and_formations():
    m = fxc_env.simulate(scenario="paper_fig1", switching="random", seed=1).metrics
    assert math.isnan(m.propagation_bound)  # no fixed sequence of graphs to count through
    assert math.isnan(m.radius_bound) and math.isnan(m.all_roots_bound)
    assert math.isfinite(m.energy_bound) and m.energy_bound > 0
    hexagon = fxc_env.simulate(scenario="formation_hexagon", seed=0).metrics
    assert hexagon.energy >= hexagon.energy_bound > 0  # E* of reaching the formation


def test_the_torchrl_env_reports_the_bounds():
    pytest.importorskip("torchrl")
    from fxc_env.policies.torchrl_reference import reference_policy

    env = fxc_env.ConsensusTorchEnv(scenario="paper_fig1", batch_size=2, device="cpu", seed=0)
    env.rollout(200, reference_policy(env))
    metrics = env.episode_metrics()
    assert np.allclose(metrics["energy_ratio"], metrics["energy"] / metrics["energy_bound"], rtol=1e-12)
    assert np.all(metrics["propagation_bound"] == 7)
    assert np.all(metrics["radius_bound"] == 5) and np.all(metrics["all_roots_bound"] == 7)


def test_episode_infos_report_the_radius_for_every_law_and_the_all_roots_bound_apart():
    # A directed ring of 45 with chords 0 -> 11, 22, 33: radius 12 (agent 0), all-roots 44 (agent 1 to 0).
    n = 45
    edges = [(i, (i + 1) % n) for i in range(n)] + [(0, 11), (0, 22), (0, 33)]
    infos = play_reference(fxc_env.parallel_env(scenario=None, topology=edges, n_agents=n, n_intervals=20))
    episode = infos["agent_0"]["episode"]
    assert (episode["radius_bound"], episode["all_roots_bound"]) == (12, 44)


def test_a_family_reports_the_bounds_of_each_episode_s_own_graph():
    from fxc_env.core.families import TopologyFamily
    from fxc_env.core.optimality import all_roots_bound, radius_bound

    config = fxc_env.make_config(scenario=None, topology=TopologyFamily("random"), n_agents=30, n_intervals=5)
    engine = ConsensusEngine(config, n_episodes=4)
    x0, v0, _, topologies = engine.draw_batch(np.random.default_rng(3))
    engine.reset(x0, v0, topologies=topologies)
    while not engine.done:
        engine.step(np.zeros((4, 30, 2)))
    metrics = engine.batch_metrics()
    assert list(metrics["radius_bound"]) == [radius_bound(t) for t in topologies]
    assert list(metrics["all_roots_bound"]) == [all_roots_bound(t) for t in topologies]
    assert len(set(metrics["all_roots_bound"])) > 1  # the graphs differ, and so do their bounds
