"""Lower bounds: the minimum energy E* and the radius (every law), the all-roots bound, the settled interval."""

from __future__ import annotations

import warnings

import networkx as nx
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg
import scipy.optimize

import fxc_env
from fxc_env.baselines.laws.minimum_time import MinimumTimePolicy
from fxc_env.config import make_config
from fxc_env.core.graphs import make_topology
from fxc_env.core.linear import LinearModel
from fxc_env.core.optimality import (
    all_roots_bound,
    energy_bound,
    episode_energy_bound,
    linear_energy_bound,
    propagation_bound,
    radius_bound,
    radius_centre,
    settled_interval,
)
from fxc_env.core.validation import ArgumentError

PAPER_X0 = np.array([1.0, -1.0, 2.0, 4.0, -4.0, -2.0])
PAPER_V0 = np.array([1.0, 2.0, 3.0, -3.0, -2.0, 0.0])


def steering_energy(start: np.ndarray, target: np.ndarray, T: float) -> float:
    """One double integrator from (x, v) to (x*, v*) in time T: 12 d²/T³ - 12 d w/T² + 4 w²/T."""
    d = target[0] - start[0] - start[1] * T
    w = target[1] - start[1]
    return 12 * d * d / T**3 - 12 * d * w / T**2 + 4 * w * w / T


def test_the_paper_example_needs_at_least_5_4597():
    assert abs(float(energy_bound(PAPER_X0, PAPER_V0, 20.0)) - 5.4597) < 1e-4


@pytest.mark.parametrize("T", [1e-300, 1e-110, 1e200, 1e300])
def test_at_extreme_settling_times_the_bound_is_its_limit_or_refused_by_name_never_inf_nan_or_overflow(T):
    """E* is beyond float64 as T_s -> 0 with any disagreement (refused naming settling_time, not inf), 0 for a
    team already in consensus, -> 0 as T_s -> inf."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning from an intermediate 0 / 0 or inf - inf
        agreed = float(energy_bound(np.full(6, 3.0), np.full(6, -1.0), T))
        moving_apart = float(energy_bound(np.zeros(6), PAPER_V0, T))  # one place, different speeds
        if T < 1:
            with pytest.raises(ArgumentError, match=r"^settling_time: E\* of episode\(s\) \[0\] is above 1.8e308"):
                energy_bound(PAPER_X0, PAPER_V0, T)
        else:
            disagreeing = float(energy_bound(PAPER_X0, PAPER_V0, T))
    assert agreed == 0.0
    w = PAPER_V0 - PAPER_V0.mean()
    assert moving_apart == pytest.approx(4.0 * np.sum(w * w) / T, rel=1e-12)  # 4 |w|² / T exactly
    if T >= 1:
        assert 0.0 < disagreeing == pytest.approx(4.0 * np.sum(w * w) / T, rel=1e-12)  # 12 s² -> 3 w²


def test_a_disagreement_whose_bound_underflows_is_refused_not_read_as_consensus():
    """Offsets of 1e-170 m at T_s = 1 s: E* ~ 1e-339 has no float64 value; 0.0 would say the team agrees."""
    tiny = np.array([0.0, 1e-170, 0.0, 0.0])
    with pytest.raises(ArgumentError, match=r"^settling_time: E\* of episode\(s\) \[1\] is below 2.2e-308"):
        energy_bound(np.stack([np.ones(4), tiny])[..., None], np.zeros((2, 4, 1)), 1.0)
    # Offsets that only underflow on the way (s² ~ 1e-320 at T_s = 1e-30 s) but whose bound is normal are computed.
    assert float(energy_bound(np.array([0.0, 1e-190]), np.zeros(2), 1e-30)) == pytest.approx(6e-290, rel=1e-12, abs=0)
    # The engine's metrics read such an episode as NaN (no answer), the others as their bound.
    z0 = np.zeros((2, 4, 2, 1))
    z0[0, :, 0, 0], z0[1, :, 0, 0] = [0.0, 1.0, 0.0, 0.0], tiny
    bound = episode_energy_bound(None, z0, 1.0)
    assert np.isnan(bound[1]) and bound[0] == pytest.approx(float(energy_bound(z0[0, :, 0], z0[0, :, 1], 1.0)))


def test_the_bound_is_the_closed_form_at_the_mean_of_the_coasted_states_batched_in_the_plane():
    rng = np.random.default_rng(7)
    x0, v0, T = rng.uniform(-5, 5, (3, 9, 2)), rng.uniform(-2, 2, (3, 9, 2)), 7.5
    bound = energy_bound(x0, v0, T)
    assert bound.shape == (3,)
    for b in range(3):
        expected = 0.0
        for axis in range(2):
            target = np.array([np.mean(x0[b, :, axis] + T * v0[b, :, axis]), np.mean(v0[b, :, axis])])
            expected += sum(steering_energy(np.array([x0[b, i, axis], v0[b, i, axis]]), target, T) for i in range(9))
        assert bound[b] == pytest.approx(expected, rel=1e-12)


@pytest.mark.slow
def test_no_common_final_state_is_cheaper_a_numerical_minimisation_for_three_agents():
    x0, v0, T = np.array([0.3, -2.0, 4.1]), np.array([1.5, -0.7, 0.2]), 3.0
    # The Gramian integral G(T) = int_0^T e^{As} B B^T e^{A^T s} ds by quadrature, for each agent's cost.
    A, B = np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]])
    gramian = scipy.integrate.quad_vec(lambda s: scipy.linalg.expm(A * s) @ B @ B.T @ scipy.linalg.expm(A.T * s), 0, T)[
        0
    ]
    motion = scipy.linalg.expm(A * T)

    def total(target):
        cost = 0.0
        for i in range(3):
            delta = target - motion @ np.array([x0[i], v0[i]])
            cost += delta @ np.linalg.solve(gramian, delta)
        return cost

    best = scipy.optimize.minimize(total, np.zeros(2), method="BFGS", options={"gtol": 1e-12})
    assert best.fun == pytest.approx(float(energy_bound(x0, v0, T)), rel=1e-8)
    assert best.x == pytest.approx([np.mean(x0 + T * v0), np.mean(v0)], abs=1e-6)


def test_the_general_bound_of_the_double_integrator_is_the_closed_form():
    model = LinearModel.named("double_integrator")
    rng = np.random.default_rng(3)
    x0, v0 = rng.uniform(-5, 5, (4, 6, 2)), rng.uniform(-2, 2, (4, 6, 2))
    z0 = np.stack([x0, v0], axis=-2)  # (B, N, n, dim)
    for T in (20.0, 1e-3):
        np.testing.assert_allclose(linear_energy_bound(model, z0, T), energy_bound(x0, v0, T), rtol=1e-12)


def test_the_general_bound_of_an_oscillator_matches_a_numerical_minimisation():
    model = LinearModel.named("oscillator", frequency=1.3)
    A, B, T = model.A, model.B, 2.0
    z0 = np.array([[1.0, 0.5], [-2.0, 0.1], [0.4, -1.2]])[:, :, None]  # (N, n, dim = 1)
    gramian = scipy.integrate.quad_vec(lambda s: scipy.linalg.expm(A * s) @ B @ B.T @ scipy.linalg.expm(A.T * s), 0, T)[
        0
    ]
    motion = scipy.linalg.expm(A * T)

    def total(target):
        return sum((target - motion @ z[:, 0]) @ np.linalg.solve(gramian, target - motion @ z[:, 0]) for z in z0)

    best = scipy.optimize.minimize(total, np.zeros(2), method="BFGS", options={"gtol": 1e-12})
    assert best.fun == pytest.approx(float(linear_energy_bound(model, z0, T)), rel=1e-7)


def test_formation_offsets_give_the_bound_of_the_formation_error():
    model = LinearModel.named("double_integrator")
    rng = np.random.default_rng(0)
    z0, h = rng.normal(size=(5, 2, 1)), np.zeros((5, 2, 1))
    h[:, 0, 0] = rng.normal(size=5)
    assert linear_energy_bound(model, z0, 4.0, offsets=h) == pytest.approx(
        float(energy_bound(z0[:, 0] - h[:, 0], z0[:, 1], 4.0)), rel=1e-12
    )
    # Agents already in formation (any common motion) need nothing.
    moved = h + np.array([[3.0], [1.0]])
    assert float(linear_energy_bound(model, moved, 4.0, offsets=h)) < 1e-24


@pytest.mark.parametrize(
    ("policy", "kwargs"),
    [
        ("reference", {"scenario": "paper_fig1"}),
        ("reference", {"scenario": "paper_fig1", "schedule": "uniform"}),
        ("reference", {"scenario": None, "topology": "complete", "n_agents": 5, "initial_state": "random"}),
        ("minimum_time", {"scenario": None, "topology": "ring", "n_agents": 6, "schedule": "uniform"}),
        ("minimum_time", {"scenario": None, "topology": "random", "n_agents": 12, "dim": 2}),
        ("minimum_time", {"scenario": None, "topology": "path", "n_agents": 6, "n_intervals": 5}),
    ],
)
def test_every_law_that_ends_below_1e_9_spent_at_least_e_star(policy, kwargs):
    config = make_config(**kwargs)
    for seed in (0, 1, 2):
        act = "reference" if policy == "reference" else MinimumTimePolicy(config)
        run = fxc_env.simulate(act, seed=seed, points_per_interval=1, **kwargs)
        assert run.metrics.relative_deadline_error < 1e-9
        bound = float(energy_bound(run.x[0], run.v[0], run.config.settling_time))
        assert run.metrics.energy >= bound > 0


def test_the_paper_numbers_the_reference_spends_far_above_e_star():
    bound = float(energy_bound(PAPER_X0, PAPER_V0, 20.0))
    paper = fxc_env.simulate("reference", "paper_fig1", points_per_interval=1)
    assert 1e7 < paper.metrics.energy / bound < 3e7  # 9.16e7 m²/s³ against 5.46
    uniform = fxc_env.simulate("reference", "paper_fig1", points_per_interval=1, schedule="uniform")
    assert 5e4 < uniform.metrics.energy / bound < 1e5  # 3.87e5 m²/s³, at the same deadline error


@pytest.mark.parametrize("n", [2, 3, 6, 20, 101])
def test_a_directed_ring_of_n_needs_n_minus_1_intervals_and_so_does_a_path(n):
    for name in ("ring", "path"):
        topology = make_topology(name, n)
        assert all_roots_bound(topology) == radius_bound(topology) == n - 1


def test_a_star_and_a_complete_graph_need_one_interval():
    assert all_roots_bound(make_topology("star", 12)) == 1
    assert all_roots_bound(make_topology("complete", 7)) == 1


def test_a_switching_period_is_counted_through_the_time_varying_graph():
    # Assumed Fig. 1: G_0 = {0->1, 3->4}, G_1 = {1->2, 4->5}, G_2 = {2->3, 5->0}. Agent 2 sends
    # first on interval 2 (G_2), then 3, 4, 5, 0 one interval each: agent 1 hears it after 7.
    assert all_roots_bound(make_topology("paper_fig1")) == 7
    # Agent 0 sends on G_0 (0->1), then 1->2, 2->3, 3->4, 4->5 one interval each: everyone after 5.
    assert radius_bound(make_topology("paper_fig1")) == 5
    # The same ring as one fixed graph: 5.
    ring = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0)]
    assert all_roots_bound(make_topology(ring, 6)) == radius_bound(make_topology(ring, 6)) == 5


def test_only_the_roots_count_on_a_graph_with_a_spanning_tree():
    # 0 <-> 1 is the root component; 1 -> 2 -> 3 hangs off it: root 0 reaches 3 in 3 hops.
    topology = make_topology([(0, 1), (1, 0), (1, 2), (2, 3)], 4)
    assert all_roots_bound(topology) == 3
    assert radius_bound(topology) == 2 and radius_centre(topology) == 1  # root 1 reaches 3 in 2 hops


def test_no_law_beats_the_radius_the_minimum_time_law_meets_it_on_a_ring():
    config = make_config(topology="ring", n_agents=7, n_intervals=12, schedule="uniform")
    run = fxc_env.simulate(
        MinimumTimePolicy(config),
        None,
        points_per_interval=1,
        topology="ring",
        n_agents=7,
        n_intervals=12,
        schedule="uniform",
    )
    errors = run.disagreement / run.disagreement[0]
    assert settled_interval(errors) == radius_bound(config.topology) == all_roots_bound(config.topology) == 6
    assert errors[5] > 1e-3  # one interval short, a root has not been heard everywhere


def test_settled_interval_counts_the_intervals_after_which_the_error_stayed_below():
    errors = np.array(
        [
            [1.0, 0.5, 1e-10, 1e-12],  # below from k = 2 on
            [1.0, 1e-10, 1e-3, 1e-12],  # dipped, came back up, below from k = 3
            [1.0, 1.0, 1.0, 1.0],  # never
            [1.0, np.nan, 1e-12, 1e-13],  # NaN counts as above
        ]
    )
    np.testing.assert_array_equal(settled_interval(errors), [2, 3, np.inf, 2])
    np.testing.assert_array_equal(settled_interval(errors, tol=0.7), [1, 1, np.inf, 2])
    assert settled_interval(np.zeros((2, 3, 5))).shape == (2, 3)


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: energy_bound([1.0, 2.0], [1.0], 1.0), "v0"),
        (lambda: energy_bound([1.0, np.nan], [1.0, 2.0], 1.0), "x0"),
        (lambda: energy_bound([1.0, 2.0], [1.0, 2.0], 0.0), "settling_time"),
        (lambda: linear_energy_bound("double_integrator", np.zeros((2, 2, 1)), 1.0), "model"),
        (lambda: linear_energy_bound(LinearModel.named("double_integrator"), np.zeros((2, 3, 1)), 1.0), "z0"),
        (lambda: all_roots_bound([(0, 1)]), "topology"),
        (lambda: radius_bound([(0, 1)]), "topology"),
        (lambda: settled_interval([1.0, 0.1], tol=-1.0), "tol"),
    ],
)
def test_bad_arguments_are_named(call, name):
    with pytest.raises(ArgumentError, match=f"^{name}:"):
        call()


def test_a_period_counts_an_agent_that_hears_from_hundreds_of_informed_senders_at_once():
    # G_0: agent 0 to agents 1..256; G_1: all of those to agent 257. The root 0 reaches 257 after 2.
    first = [(0, i) for i in range(1, 257)]
    second = [(j, 257) for j in range(1, 257)]
    assert (
        all_roots_bound(make_topology([first, second], 258)) == radius_bound(make_topology([first, second], 258)) == 2
    )


def held_out_digraph(rng: np.random.Generator, n: int, extra: int) -> list[tuple[int, int]]:
    """A random digraph with a directed spanning tree: a random tree plus ``extra`` random edges (j, i)."""
    order = rng.permutation(n)
    edges = {(int(order[rng.integers(0, k)]), int(order[k])) for k in range(1, n)}
    while len(edges) < n - 1 + extra:
        j, i = (int(a) for a in rng.choice(n, size=2, replace=False))
        edges.add((j, i))
    return sorted(edges)


def eccentricities_by_networkx(edges: list[tuple[int, int]], n: int) -> np.ndarray:
    """Per agent r, max_i dist(r -> i) along the edges j -> i (inf where r does not reach everyone)."""
    graph = nx.DiGraph(edges)
    graph.add_nodes_from(range(n))
    out = np.full(n, np.inf)
    for r in range(n):
        lengths = nx.single_source_shortest_path_length(graph, r)
        if len(lengths) == n:
            out[r] = max(lengths.values())
    return out


def reach_by_time_respecting_search(period: list[list[tuple[int, int]]], n: int) -> np.ndarray:
    """Per agent r, the fewest intervals until r's initial state has reached everyone (inf if never).

    Interval k uses graph k mod m; an agent informed by t_k informs its out-neighbours of that graph by t_{k+1}.
    """
    out = np.full(n, np.inf)
    for r in range(n):
        informed, k = {r}, 0
        while len(informed) < n and k <= len(period) * n:
            informed = informed | {i for j, i in period[k % len(period)] if j in informed}
            k += 1
        if len(informed) == n:
            out[r] = k
    return out


@pytest.mark.parametrize("seed", range(12))
def test_radius_and_all_roots_bounds_equal_an_independent_graph_search_on_held_out_digraphs(seed):
    rng = np.random.default_rng(10_000 + seed)
    n = int(rng.integers(4, 60))
    edges = held_out_digraph(rng, n, extra=int(rng.integers(0, n)))
    topology = make_topology(edges, n)
    eccentricity = eccentricities_by_networkx(edges, n)
    roots = np.isfinite(eccentricity)
    assert radius_bound(topology) == eccentricity.min()
    assert eccentricity[radius_centre(topology)] == eccentricity.min()
    # The all-roots bound: the largest eccentricity among the roots (those that reach everyone).
    assert all_roots_bound(topology) == eccentricity[roots].max()


@pytest.mark.parametrize("seed", range(8))
def test_switching_bounds_equal_an_independent_time_respecting_search(seed):
    rng = np.random.default_rng(20_000 + seed)
    n, m = int(rng.integers(4, 25)), int(rng.integers(2, 4))
    edges = held_out_digraph(rng, n, extra=int(rng.integers(0, n)))
    slot = rng.integers(0, m, size=len(edges))
    period = [[e for e, g in zip(edges, slot, strict=True) if g == s] for s in range(m)]
    topology = make_topology(period, n)
    reach = reach_by_time_respecting_search(period, n)
    assert radius_bound(topology) == reach.min()
    assert all_roots_bound(topology) == reach[np.isfinite(reach)].max()
    assert reach[radius_centre(topology)] == reach.min()


def test_a_ring_with_chords_has_a_radius_far_below_its_all_roots_bound():
    # A directed ring of 45 with three chords out of agent 0, to 11, 22 and 33 (this project's own
    # construction): agent 0 reaches everyone within 12 hops, but agent 1 reaches agent 0 only
    # around the ring, 44 hops. A law following agent 0 can be exact after 12 intervals; a law
    # whose value depends on every root (the paper's) not before 44.
    n = 45
    edges = [(i, (i + 1) % n) for i in range(n)] + [(0, 11), (0, 22), (0, 33)]
    topology = make_topology(edges, n)
    eccentricity = eccentricities_by_networkx(edges, n)
    assert radius_bound(topology) == eccentricity.min() == 12 and radius_centre(topology) == 0
    assert all_roots_bound(topology) == eccentricity.max() == 44


def test_propagation_bound_is_a_deprecated_alias_of_the_all_roots_bound():
    topology = make_topology("paper_fig1")
    with pytest.warns(DeprecationWarning, match="all_roots_bound"):
        assert propagation_bound(topology) == all_roots_bound(topology) == 7
