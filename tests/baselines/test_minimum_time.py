"""The minimum-time law: exact consensus in one interval per eigenvalue, in every mode, and its refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import fxc_env
from fxc_env.baselines import MinimumTimePolicy
from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import BenchmarkCase, builtin_contenders, load_policy
from fxc_env.baselines.laws.minimum_time import design_eigenvalues, leja_factors
from fxc_env.config import make_config
from fxc_env.config.scenarios import HEXAGON
from fxc_env.core.families import TopologyFamily
from fxc_env.core.graphs import make_topology
from fxc_env.core.optimality import radius_bound
from fxc_env.core.validation import ArgumentError

MODES = [("plan", "normalized"), ("plan", "raw"), ("accel", "normalized"), ("accel", "raw")]


def run(seed=0, **kwargs):
    """One episode of the law; the relative disagreement D(t_k)/D(0) at every instant, and the trajectory."""
    kwargs = {"scenario": None, **kwargs}
    policy = MinimumTimePolicy(make_config(**kwargs))
    trajectory = fxc_env.simulate(policy, seed=seed, points_per_interval=1, **kwargs)
    return trajectory.disagreement / trajectory.disagreement[0], trajectory


@pytest.mark.parametrize("n", [3, 4, 5, 6, 8])
@pytest.mark.parametrize(("action_mode", "obs_mode"), MODES)
@pytest.mark.parametrize("schedule", ["paper", "uniform"])
def test_a_directed_ring_of_n_agrees_exactly_after_n_minus_1_intervals(n, action_mode, obs_mode, schedule):
    errors, _ = run(
        topology="ring", n_agents=n, n_intervals=n - 1, schedule=schedule, action_mode=action_mode, obs_mode=obs_mode
    )
    assert errors[-1] <= 1e-12
    assert errors[-2] > 1e-6  # not one interval earlier: the propagation bound


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_a_path_repeats_its_eigenvalue_one_half_and_agrees_after_n_minus_1_intervals(dim):
    eigenvalues = design_eigenvalues(make_topology("path", 9))
    np.testing.assert_array_equal(eigenvalues, np.full(8, 0.5))  # one Jordan block of size 8
    errors, _ = run(topology="path", n_agents=9, n_intervals=8, dim=dim, schedule="uniform")
    assert errors[-1] <= 1e-12 and errors[-2] > 1e-6


def test_a_ring_of_20_at_k_200_ends_below_1e_12_on_both_schedules_at_the_papers_final_value():
    contender = builtin_contenders(["minimum_time"])[0]
    for schedule in ("uniform", "paper"):
        case = BenchmarkCase("ring", 20)
        result = run_job(Job(replace(contender, schedule=schedule), case, 200, tuple(range(5)), 20.0, False))
        assert result.error is None
        assert np.max(result.metrics["relative_deadline_error"]) <= 1e-12
        # Theorem 1's value xi^T x(0) + T_s xi^T v(0): every factor is a polynomial of W-hat equal to 1 at 0.
        assert np.max(result.metrics["final_value_gap"]) <= 1e-9


def test_random_digraphs_and_stars_reach_round_off():
    for topology, n in (("random", 20), ("star", 15), ("complete", 6)):
        errors, _ = run(topology=topology, n_agents=n, n_intervals=200, schedule="uniform")
        assert errors[-1] <= 1e-12, topology


def test_formation_offsets_are_reached():
    errors, trajectory = run(topology="ring", n_agents=6, n_intervals=5, formation_offsets=HEXAGON, dim=2)
    assert errors[-1] <= 1e-12
    gaps = trajectory.x[-1] - trajectory.x[-1].mean(axis=0)
    offsets = trajectory.config.formation[:, 0]
    np.testing.assert_allclose(gaps, offsets - offsets.mean(axis=0), atol=1e-9)


def test_fewer_intervals_than_factors_plays_the_first_ones_and_says_there_is_no_guarantee():
    with pytest.warns(UserWarning, match=r"^n_intervals: K = 6 is below the 11 intervals"):
        policy = MinimumTimePolicy(make_config(topology="ring", n_agents=12, n_intervals=6))
    assert policy.needed_intervals == 11 and policy.factor_intervals <= 6
    assert policy.guarantee().startswith("no exact guarantee")
    assert MinimumTimePolicy(make_config(topology="ring", n_agents=12, n_intervals=11)).guarantee().startswith("exact")


@pytest.mark.parametrize(("topology", "n"), [("ring", 40), ("random", 60)])
def test_with_fewer_intervals_than_factors_it_does_no_worse_than_the_papers_plan(topology, n):
    kwargs = {"topology": topology, "n_agents": n, "n_intervals": 20, "schedule": "uniform"}
    with pytest.warns(UserWarning, match="^n_intervals:"):
        policy = MinimumTimePolicy(make_config(**kwargs))
    assert policy.needed_intervals > 20
    for seed in (0, 1):
        with pytest.warns(UserWarning, match="^n_intervals:"):
            errors, _ = run(seed, **kwargs)
        reference = fxc_env.simulate("reference", None, seed=seed, points_per_interval=1, **kwargs)
        assert errors[-1] <= reference.metrics.relative_deadline_error * (1 + 1e-9)


def test_leja_order_starts_at_the_largest_eigenvalue_and_keeps_each_complex_pair_as_one_factor():
    eigenvalues = design_eigenvalues(make_topology("ring", 10))
    factors = leja_factors(eigenvalues)
    assert sum(f.intervals for f in factors) == 9
    assert abs(factors[0].eigenvalue) == pytest.approx(np.max(np.abs(eigenvalues)))
    assert all(f.eigenvalue.imag >= 0 for f in factors)


def test_it_reads_dict_observations_and_batches_like_the_other_baselines():
    config = make_config(topology="ring", n_agents=6, obs_format="dict")
    env = fxc_env.parallel_env(topology="ring", n_agents=6, obs_format="dict")
    observations, _ = env.reset(seed=0)
    policy = MinimumTimePolicy(env)
    flat = np.stack([config.layout.flat(observations[a]) for a in env.agents])
    batched = policy(flat)
    for i, agent in enumerate(env.agents):
        np.testing.assert_array_equal(policy(observations[agent]), batched[i])


def test_it_is_registered_for_the_benchmark_and_fxc_evaluate():
    config = make_config(topology="ring", n_agents=6)
    assert isinstance(load_policy("minimum_time", config), MinimumTimePolicy)
    assert "minimum_time" in [c.name for c in builtin_contenders()]


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"topology": "ring", "n_agents": 6, "u_max": 10.0}, "u_max"),
        ({"topology": "ring", "n_agents": 6, "obs_noise": 1e-3}, "obs_noise"),
        ({"topology": "ring", "n_agents": 6, "link_dropout": 0.1}, "link_dropout"),
        ({"topology": "random", "n_agents": 8, "topology_period": 2, "switching": "random"}, "topology"),
        ({"topology": "ring", "n_agents": 6, "switching": "random"}, "switching"),
        ({"topology": "paper_fig1"}, "topology"),
        ({"topology": TopologyFamily("ring"), "n_agents": 6}, "topology"),
        ({"topology": "ring", "n_agents": 6, "agent_model": {"name": "integrator_chain", "order": 3}}, "agent_model"),
        ({"topology": "ring", "n_agents": 6, "agent_model": ([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]])}, "agent_model"),
    ],
)
def test_it_refuses_by_name_what_it_cannot_honour(kwargs, name):
    config = make_config(scenario=None, **kwargs)
    with pytest.raises(ArgumentError, match=f"^({name}):"):
        MinimumTimePolicy(config)


def test_a_refused_case_is_reported_as_not_run_in_the_benchmark():
    contender = builtin_contenders(["minimum_time"])[0]
    result = run_job(Job(contender, BenchmarkCase("paper_fig1", 6), 50, (0, 1), 20.0, False))
    assert result.error is not None and result.error.startswith("topology:")


@pytest.mark.slow
def test_fxc_evaluate_with_baselines_scores_it(tmp_path):
    import csv

    from fxc_env.cli import main

    argv = ["evaluate", "--policy", "reference", "--baselines", "--seeds", "2", "--out", str(tmp_path), "--no-progress"]
    assert main([*argv, "--topology", "ring", "--n-agents", "8"]) == 0
    rows = {r["policy"]: r for r in csv.DictReader((tmp_path / "results.csv").open())}
    assert rows["minimum_time"]["error"] == ""
    assert float(rows["minimum_time"]["relative_deadline_error_q75"]) <= 1e-12
    assert float(rows["minimum_time"]["settled_interval_median"]) == 7  # N - 1


#: A binary tree of 31 agents, edges parent -> child: depth 4, every non-root eigenvalue 1/2 (Jordan blocks up to 4).
BINARY_TREE = [((i - 1) // 2, i) for i in range(1, 31)]


@pytest.mark.parametrize("k", [4, 8])
def test_a_binary_tree_is_exact_at_its_depth_its_eigenvalue_repeated_by_its_jordan_block(k):
    # 30 eigenvalues 1/2 but a minimal polynomial (1 - 2 mu)^4: four factors, copying the parent four times.
    np.testing.assert_array_equal(design_eigenvalues(make_topology(BINARY_TREE, 31)), np.full(4, 0.5))
    policy = MinimumTimePolicy(make_config(scenario=None, topology=BINARY_TREE, n_agents=31, n_intervals=k))
    assert policy.needed_intervals == radius_bound(make_topology(BINARY_TREE, 31)) == 4
    assert policy.predicted_residual == 0.0
    for seed in (0, 1, 2):
        errors, _ = run(seed, topology=BINARY_TREE, n_agents=31, n_intervals=k, schedule="uniform")
        assert errors[-1] <= 1e-12


def test_below_the_factors_it_needs_it_warns_and_predicts_the_residual_it_leaves():
    kwargs = {"topology": BINARY_TREE, "n_agents": 31, "n_intervals": 3, "schedule": "uniform"}
    with pytest.warns(UserWarning, match=r"^n_intervals: K = 3 is below the 4 intervals MinimumTimePolicy needs"):
        policy = MinimumTimePolicy(make_config(scenario=None, **kwargs))
    assert policy.guarantee().startswith("no exact guarantee")
    with pytest.warns(UserWarning):
        errors, _ = run(0, **kwargs)
    # The prediction is the largest gain on a disagreement (2-norm); the run's D(T_s)/D(0) is of its order.
    assert policy.predicted_residual > 0.1 and errors[-1] > 0.1
    assert 0.2 < errors[-1] / policy.predicted_residual < 5.0


@pytest.mark.parametrize("seed", range(6))
def test_held_out_graphs_with_repeated_eigenvalues_are_exact_after_the_factors_it_needs(seed):
    # A random tree plus edges whose receivers often keep in-degree 1 or 2: many components share an eigenvalue.
    rng = np.random.default_rng(50_000 + seed)
    n = int(rng.integers(10, 40))
    order = rng.permutation(n)
    edges = {(int(order[rng.integers(0, k)]), int(order[k])) for k in range(1, n)}
    for _ in range(int(rng.integers(0, n // 2))):
        k = int(rng.integers(2, n))
        edges.add((int(order[rng.integers(0, k)]), int(order[k])))  # from an earlier agent: a DAG
    edges = sorted(edges)
    policy = MinimumTimePolicy(make_config(scenario=None, topology=edges, n_agents=n, n_intervals=n - 1))
    needed = policy.needed_intervals
    assert radius_bound(make_topology(edges, n)) <= needed <= n - 1
    errors, _ = run(seed, topology=edges, n_agents=n, n_intervals=needed, schedule="uniform")
    assert errors[-1] <= 1e-12
