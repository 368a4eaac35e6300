"""Floors under measurement noise and input limits: what no controller can beat (docs: optimality.md, "How far from optimal")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.optimize
import scipy.sparse

import fxc_env
from fxc_env.baselines.harness.jobs import Job, JobResult, run_job
from fxc_env.baselines.harness.suite import BenchmarkCase, Contender, load_policy
from fxc_env.baselines.laws.minimum_time import MinimumTimePolicy
from fxc_env.baselines.laws.signalling import SignallingPolicy
from fxc_env.config import make_config
from fxc_env.core.floors import input_floor, input_floor_bounds, noise_floor
from fxc_env.core.graphs import make_topology
from fxc_env.core.validation import ArgumentError
from fxc_env.engine.draws import draw_episode

T_S = 20.0


def ring_states(schedule: str = "uniform", seeds: range = range(5)) -> tuple:
    config = make_config(topology="ring", n_agents=20, n_intervals=200, settling_time=T_S, schedule=schedule)
    draws = [draw_episode(config, np.random.default_rng(seed)) for seed in seeds]
    return config, [(d.x0, d.v0) for d in draws]


def disagreement(x: np.ndarray, v: np.ndarray) -> float:
    return float(np.ptp(x) + T_S * np.ptp(v))


@pytest.mark.parametrize(("schedule", "expected"), [("uniform", 2.0e-5), ("paper", 4.4e-5)])
def test_the_noise_floor_of_a_ring_of_20_at_sigma_1e_3(schedule, expected):
    config, states = ring_states(schedule)
    floor = noise_floor(config.topology, config.schedule.times, 1e-3)
    relative = np.median([floor / disagreement(x, v) for x, v in states])
    assert relative == pytest.approx(expected, rel=0.03)


def test_the_noise_floor_of_two_agents_is_the_least_squares_error_in_closed_form():
    """One edge: the relative state's estimate has covariance sigma² (sum_k Phi_k^T Phi_k)^-1, D = |dx + T dv| + T |dv|."""
    times = np.linspace(0.0, T_S, 11)
    gram = sum(np.array([[1.0, t], [t, 1.0 + t * t]]) for t in times[:-1])
    covariance = np.linalg.inv(gram)
    final = np.array([1.0, T_S])
    expected = np.sqrt(2 / np.pi) * (np.sqrt(final @ covariance @ final) + T_S * np.sqrt(covariance[1, 1]))
    floor = noise_floor(make_topology("path", 2), times, 0.5)
    assert floor == pytest.approx(0.5 * expected, rel=0.02)
    assert noise_floor(make_topology("path", 2), times, 1.0) == pytest.approx(2 * floor, rel=1e-12)  # linear in sigma


def test_the_noise_floor_is_infinite_where_the_rows_cannot_tell_the_disagreement():
    disconnected = fxc_env.core.graphs.Topology(3, (np.array([[0, 1]]),))
    assert noise_floor(disconnected, np.linspace(0.0, 1.0, 5), 1e-3) == np.inf
    with pytest.raises(ArgumentError, match="sigma"):
        noise_floor(make_topology("ring", 4), np.linspace(0.0, 1.0, 5), -1.0)


def test_the_input_floor_of_a_ring_of_20_is_0_21_to_0_26_below_the_e_star_steer_s_0_42():
    _, states = ring_states()
    floors = [input_floor(x, v, T_S) for x, v in states]
    assert round(min(floors), 2) == 0.21 and round(max(floors), 2) == 0.26
    peaks = []
    for x, v in states:  # the minimum-energy steer u(t) = a + b t to the mean prediction (E*)
        p, w = x[:, 0] + T_S * v[:, 0], v[:, 0]
        moments = np.array([[T_S, T_S**2 / 2], [T_S**2 / 2, T_S**3 / 6]])
        a, b = np.linalg.solve(moments, np.stack([w.mean() - w, p.mean() - p]))
        peaks.append(np.max(np.abs(np.r_[a, a + b * T_S])))
    assert round(float(np.median(peaks)), 2) == 0.42
    assert all(floor < peak for floor, peak in zip(floors, peaks, strict=True))


def direct_programme(x: np.ndarray, v: np.ndarray, pieces: int, limit: float | None) -> scipy.optimize.OptimizeResult:
    """Exact consensus with piecewise-constant inputs on ``pieces`` equal pieces: min U (``limit`` None) or feasibility at U."""
    n, h = len(x), T_S / pieces
    starts = h * np.arange(pieces)
    lever = (T_S - starts) * h - h * h / 2  # int over piece k of (T_s - t)
    # variables: u (n * pieces), x*, v*, U; equalities per agent: sum u h = v* - v_i, sum u lever = x* - x_i - v_i T_s.
    width = n * pieces + 3
    equalities, targets = [], []
    for i in range(n):
        for weights, column, value in ((np.full(pieces, h), -2, -v[i]), (lever, -3, -(x[i] + v[i] * T_S))):
            row = np.zeros(width)
            row[i * pieces : (i + 1) * pieces] = weights
            row[column] = -1.0
            equalities.append(row)
            targets.append(value)
    # |u| <= U
    identity = scipy.sparse.identity(n * pieces, format="csr")
    limit_column = scipy.sparse.csr_array(-np.ones((2 * n * pieces, 1)))
    bound_rows = scipy.sparse.hstack(
        [scipy.sparse.vstack([identity, -identity]), scipy.sparse.csr_array((2 * n * pieces, 2)), limit_column]
    )
    last = (0.0, None) if limit is None else (limit, limit)
    return scipy.optimize.linprog(
        c=np.r_[np.zeros(width - 1), 1.0],
        A_ub=bound_rows,
        b_ub=np.zeros(2 * n * pieces),
        A_eq=scipy.sparse.csr_array(np.array(equalities)),
        b_eq=np.array(targets),
        bounds=[(None, None)] * (width - 1) + [last],
        method="highs",
    )


def test_exact_consensus_is_feasible_at_the_input_floor_and_infeasible_below():
    _, states = ring_states(seeds=range(1))
    x, v = states[0][0][:, 0], states[0][1][:, 0]
    lower, upper = input_floor_bounds(x, v, T_S, facets=64)
    assert lower < upper < lower * (1 + 1e-3)
    # Inputs directly (another programme): on 64 pieces, the least limit is the inner polygon's.
    direct = direct_programme(x, v, 64, None)
    assert direct.status == 0 and direct.x[-1] == pytest.approx(upper, rel=1e-7)
    # Its inputs, integrated exactly, bring every agent to one state within the limit.
    u = direct.x[: 20 * 64].reshape(20, 64)
    h = T_S / 64
    velocity = v + u.sum(axis=1) * h
    position = x + v * T_S + (u * ((T_S - h * np.arange(64)) * h - h * h / 2)).sum(axis=1)
    assert np.ptp(velocity) < 1e-9 and np.ptp(position) < 1e-9 and np.max(np.abs(u)) <= upper * (1 + 1e-7)
    # Below the floor no input reaches consensus, however fine the pieces.
    assert direct_programme(x, v, 128, 0.999 * input_floor(x, v, T_S)).status == 2


def test_the_episode_infos_carry_the_floors_of_the_settings_they_have():
    def episode_end(**kwargs):
        env = fxc_env.parallel_env(topology="ring", n_agents=20, n_intervals=20, settling_time=T_S, **kwargs)
        env.reset(seed=1)
        while env.agents:
            _, _, _, _, infos = env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
        return next(iter(infos.values()))["episode"]

    config, states = ring_states(seeds=range(1, 2))
    x, v = states[0]
    noisy = episode_end(obs_noise=1e-3)
    times = make_config(topology="ring", n_agents=20, n_intervals=20, settling_time=T_S).schedule.times
    assert noisy["noise_floor"] == pytest.approx(noise_floor(config.topology, times, 1e-3) / disagreement(x, v))
    assert "input_floor" not in noisy
    limited = episode_end(u_max=0.3)
    assert limited["input_floor"] == pytest.approx(input_floor(x, v, T_S)) and "noise_floor" not in limited
    assert not {"noise_floor", "input_floor"} & set(episode_end())


def opted_in(spec: str, schedule: str, case: BenchmarkCase, seeds: tuple[int, ...] = (0, 1, 2)) -> dict:
    obs_mode = "normalized" if spec.startswith("minimum_time") else "raw"
    result = run_job(Job(Contender(spec, spec, True, schedule, "plan", obs_mode), case, 200, seeds, T_S, False))
    assert result.error is None, result.error
    return result.metrics


def test_minimum_time_runs_under_noise_only_when_asked_and_degrades_linearly():
    noisy = make_config(topology="ring", n_agents=20, n_intervals=200, schedule="uniform", obs_noise=1e-6)
    with pytest.raises(ArgumentError, match=r"obs_noise.*allow_noise=True"):
        MinimumTimePolicy(noisy)
    ring = BenchmarkCase("ring", 20)
    errors = [
        np.median(
            opted_in("minimum_time/noisy", "uniform", replace(ring, conditions=(("obs_noise", s),)))[
                "relative_deadline_error"
            ]
        )
        for s in (1e-6, 1e-4)
    ]
    assert 1e-7 < errors[0] < 1e-5 and errors[1] / errors[0] == pytest.approx(100, rel=0.05)
    with pytest.raises(ArgumentError, match="obs_noise"):
        load_policy("minimum_time/noisy", make_config(topology="ring", n_agents=20))


def test_signalling_runs_under_an_input_limit_only_when_asked_and_is_exact_where_the_limit_never_binds():
    limited = make_config(scenario="paper_fig1", schedule="uniform", obs_mode="raw", u_max=10.0)
    with pytest.raises(ArgumentError, match=r"u_max.*allow_limit=True"):
        SignallingPolicy(limited)
    metrics = opted_in("signalling/limited", "uniform", BenchmarkCase("paper_fig1", 6, conditions=(("u_max", 10.0),)))
    assert np.max(metrics["relative_deadline_error"]) < 1e-9 and np.max(metrics["saturated_fraction"]) == 0
    assert np.max(metrics["peak_input"]) < 10.0


def test_fxc_simulate_prints_the_floors_of_its_settings(tmp_path, capsys):
    from fxc_env.cli.main import main

    args = ["simulate", "--scenario", "paper_fig1", "--n-intervals", "20", "--out", str(tmp_path)]
    assert main([*args, "--u-max", "10", "--obs-noise", "1e-3"]) == 0
    text = capsys.readouterr().out
    assert "D(T_s)/D(0) under the noise" in text and "u_max of exact consensus (m/s²)" in text
    assert main(args) == 0
    assert "under the noise" not in capsys.readouterr().out


def test_the_benchmark_tables_carry_the_floors_of_cases_with_noise_or_a_limit():
    from fxc_env.baselines.harness import report
    from fxc_env.baselines.harness.suite import floor_cases, optimality_contenders, quick_optimality_suite

    suite = quick_optimality_suite(2)
    contenders = optimality_contenders()[:2]
    results = []
    for case in suite.cases:
        for contender in contenders:
            result = JobResult(Job(contender, case, 200, (0, 1), T_S, False))
            ones = np.ones(2)
            result.metrics = {
                name: ones
                for name in ("relative_deadline_error", "saturated_fraction", "energy", "energy_bound", "energy_ratio")
            }
            result.metrics |= {
                "settled_interval": np.full(2, np.inf),
                "radius_bound": 19 * ones,
                "all_roots_bound": 19 * ones,
            }
            result.metrics["noise_floor"] = 2e-5 * ones if "obs_noise" in case.key else np.full(2, np.nan)
            result.metrics["input_floor"] = 0.23 * ones if "u_max" in case.key else np.full(2, np.nan)
            results.append(result)
    assert set(floor_cases()) <= set(suite.cases)
    for table in (report.case_table, report.realism_table, report.optimality_table):
        text = table(results, suite, contenders)
        assert "D/D(0) ≥ 2e-05" in text and "u_max ≥ 0.23" in text, table.__name__
