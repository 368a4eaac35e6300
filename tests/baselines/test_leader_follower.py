"""The leader-follower law: exact consensus after exactly the radius, the bound for every law."""

from __future__ import annotations

import numpy as np
import pytest

import fxc_env
from fxc_env.baselines import LeaderFollowerPolicy
from fxc_env.baselines.harness.figures import style_at
from fxc_env.baselines.harness.suite import BASELINES, BUILTIN_SETTINGS, load_policy, optimality_contenders
from fxc_env.config import make_config
from fxc_env.core.families import TopologyFamily
from fxc_env.core.graphs import make_topology
from fxc_env.core.optimality import all_roots_bound, radius_bound
from fxc_env.core.validation import ArgumentError


def held_out_digraph(rng: np.random.Generator, n: int, extra: int) -> list[tuple[int, int]]:
    """A random digraph with a directed spanning tree: a random tree plus ``extra`` random edges (j, i)."""
    order = rng.permutation(n)
    edges = {(int(order[rng.integers(0, k)]), int(order[k])) for k in range(1, n)}
    while len(edges) < n - 1 + extra:
        j, i = (int(a) for a in rng.choice(n, size=2, replace=False))
        edges.add((j, i))
    return sorted(edges)


def deadline_error(topology, n: int, k: int, seed: int = 0, **kwargs) -> float:
    settings = {"scenario": None, "topology": topology, "n_agents": n, "n_intervals": k, "schedule": "uniform"}
    settings.update(kwargs)
    policy = LeaderFollowerPolicy(make_config(**settings))
    return fxc_env.simulate(policy, seed=seed, points_per_interval=1, **settings).metrics.relative_deadline_error


@pytest.mark.parametrize("seed", range(6))
def test_exact_after_exactly_the_radius_on_held_out_fixed_digraphs(seed):
    rng = np.random.default_rng(30_000 + seed)
    n = int(rng.integers(8, 40))
    edges = held_out_digraph(rng, n, extra=int(rng.integers(0, n)))
    radius = radius_bound(make_topology(edges, n))
    assert deadline_error(edges, n, radius, seed=seed) <= 1e-12
    if radius > 1:
        assert deadline_error(edges, n, radius - 1, seed=seed) > 1e-3  # one interval short: no law is exact


@pytest.mark.parametrize("seed", range(4))
def test_exact_after_the_time_respecting_radius_on_held_out_switching_periods(seed):
    rng = np.random.default_rng(40_000 + seed)
    n, m = int(rng.integers(6, 20)), int(rng.integers(2, 4))
    edges = held_out_digraph(rng, n, extra=int(rng.integers(0, n)))
    slot = rng.integers(0, m, size=len(edges))
    period = [[e for e, g in zip(edges, slot, strict=True) if g == s] for s in range(m)]
    radius = radius_bound(make_topology(period, n))
    assert deadline_error(period, n, radius, seed=seed) <= 1e-12
    if radius > 1:
        assert deadline_error(period, n, radius - 1, seed=seed) > 1e-3


def test_the_ring_with_chords_is_exact_at_its_radius_long_before_its_all_roots_bound():
    n = 45
    edges = [(i, (i + 1) % n) for i in range(n)] + [(0, 11), (0, 22), (0, 33)]
    topology = make_topology(edges, n)
    assert (radius_bound(topology), all_roots_bound(topology)) == (12, 44)
    policy = LeaderFollowerPolicy(make_config(scenario=None, topology=edges, n_agents=n, n_intervals=12))
    assert policy.centre == 0 and policy.needed_intervals == 12
    assert deadline_error(edges, n, 12) <= 1e-12


@pytest.mark.parametrize(
    ("action_mode", "obs_mode", "dim", "schedule"),
    [
        ("plan", "normalized", 1, "uniform"),
        ("plan", "raw", 2, "paper"),
        ("accel", "raw", 1, "paper"),
        ("accel", "normalized", 3, "uniform"),
    ],
)
def test_every_mode_dimension_and_schedule_is_exact_on_the_paper_s_switching_ring(action_mode, obs_mode, dim, schedule):
    # The assumed Fig. 1: radius 5 through the time-varying graph (the all-roots bound is 7).
    kwargs = {"action_mode": action_mode, "obs_mode": obs_mode, "dim": dim, "schedule": schedule}
    assert deadline_error("paper_fig1", 6, 5, **kwargs) <= 1e-12
    assert deadline_error("paper_fig1", 6, 4, **kwargs) > 1e-3


def test_each_agent_acts_on_its_own_observation_only():
    config = make_config(scenario=None, topology="random", n_agents=12, n_intervals=10)
    policy = LeaderFollowerPolicy(config)
    env = fxc_env.parallel_env(scenario=None, topology="random", n_agents=12, n_intervals=10)
    observations, _ = env.reset(seed=0)
    obs = np.stack([observations[a] for a in env.agents])
    actions = policy(obs)
    scrambled = np.random.default_rng(1).normal(size=obs.shape)
    for i in range(12):
        mixed = scrambled.copy()
        mixed[i] = obs[i]  # every other agent's observation replaced by noise
        np.testing.assert_array_equal(policy(mixed)[i], actions[i])


def test_it_is_a_registered_baseline_with_its_settings():
    assert BASELINES["leader_follower"] is LeaderFollowerPolicy
    assert BUILTIN_SETTINGS["leader_follower"] == (True, "uniform", "plan", "normalized")
    laws = [c.name for c in optimality_contenders()]
    assert "leader_follower" in laws
    assert len({style_at(i) for i in range(len(laws))}) == len(laws)  # its own marker and colour on the frontier
    policy = load_policy("leader_follower", make_config(scenario=None, topology="ring", n_agents=5))
    assert isinstance(policy, LeaderFollowerPolicy) and policy.guarantee().startswith("exact")
    short = LeaderFollowerPolicy(make_config(scenario=None, topology="ring", n_agents=9, n_intervals=7))
    assert short.guarantee().startswith("no exact guarantee: K = 7 < 8")


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"topology": TopologyFamily("ring")}, "topology"),
        ({"topology": "paper_fig1", "switching": "random"}, "switching"),
        ({"u_max": 10.0}, "u_max"),
        ({"obs_noise": 1e-3}, "obs_noise"),
        ({"link_dropout": 0.1}, "link_dropout"),
        ({"agent_model": "single_integrator"}, "agent_model"),
    ],
)
def test_it_refuses_what_it_cannot_honour_by_name(kwargs, name):
    settings = {"scenario": None, "topology": "ring", "n_agents": 6, **kwargs}
    with pytest.raises(ArgumentError, match=f"^{name}:"):
        LeaderFollowerPolicy(make_config(**settings))


def test_a_bad_centre_or_observation_is_named():
    # 0 <-> 1 is the root component; 1 -> 2 -> 3 hangs off it: 2 reaches no root.
    config = make_config(scenario=None, topology=[(0, 1), (1, 0), (1, 2), (2, 3)], n_agents=4)
    assert LeaderFollowerPolicy(config).centre == 1  # reaches 3 in 2 hops; root 0 needs 3
    assert LeaderFollowerPolicy(config, centre=0).needed_intervals == 3
    for centre in (2, 7, 1.0, True):
        with pytest.raises(ArgumentError, match=r"^centre:"):
            LeaderFollowerPolicy(config, centre=centre)
    with pytest.raises(ArgumentError, match=r"^observation:"):
        LeaderFollowerPolicy(config)(np.zeros((3, config.layout.size)))
