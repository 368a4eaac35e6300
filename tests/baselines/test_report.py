"""Medians with spread: quantiles, cells and the per-job CSV rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fxc_env.baselines.harness.jobs import Job, JobResult
from fxc_env.baselines.harness.report import (
    CSV_METRICS,
    aggregate,
    case_table,
    exact_share,
    headline_table,
    optimality_table,
    quantiles,
    realism_table,
    spread_cell,
)
from fxc_env.baselines.harness.suite import BenchmarkCase, Suite, builtin_contenders


def test_quantiles_ignore_nan_and_rank_inf_last():
    median, q25, q75 = quantiles(np.array([np.nan, 1.0, 2.0, 3.0, 4.0, np.inf]))
    assert (median, q25, q75) == (3.0, 2.0, 4.0)
    assert all(math.isnan(q) for q in quantiles(np.array([np.nan])))


def test_spread_cell_reads_median_then_interquartile_range():
    assert spread_cell(np.array([1e-12, 2e-12, 3e-12, 4e-12, 5e-12])) == "3e-12 [2e-12, 4e-12]"
    assert spread_cell(np.array([np.inf, np.inf])) == "∞ [∞, ∞]"


def test_aggregate_counts_divergence_and_deadlines_met():
    job = Job(builtin_contenders(["linear"])[0], BenchmarkCase("ring", 6), 100, (0, 1, 2, 3), 20.0, False)
    relative = np.array([1e-9, 1e-3, np.inf, 1e-7])
    metrics = {name: np.ones(4) for name in CSV_METRICS}
    metrics.update(relative_deadline_error=relative)
    row = aggregate([JobResult(job, metrics=metrics, parameters={"gamma": 2.0})])[0]
    assert row["diverged"] == 1
    assert row["met_1e-6"] == 0.5
    assert row["relative_deadline_error_median"] == 1e-7  # lower median of [1e-9, 1e-7, 1e-3, inf]
    assert (row["case"], row["n_intervals"], row["schedule"], row["parameters"]) == (
        "ring N=6",
        100,
        "uniform",
        "gamma=2",
    )


def split_results():
    """One job whose median (1e-9, exact) hides a two-way split: three exact seeds, two at 0.03 and 0.1."""
    case = BenchmarkCase("ring", 20, conditions=(("u_max", 0.3),))
    contender = builtin_contenders(["bounded_steer"])[0]
    relative = np.array([1e-12, 0.03, 5e-10, 0.1, 1e-9])
    metrics = {name: np.ones(5) for name in CSV_METRICS}
    metrics.update(
        relative_deadline_error=relative,
        energy_bound=np.ones(5),
        energy_ratio=np.full(5, 2.0),
        settled_interval=np.full(5, 19.0),
        radius_bound=np.full(5, 19.0),
        all_roots_bound=np.full(5, 19.0),
        input_floor=np.full(5, 0.22),
    )
    suite = Suite(cases=(case,), seeds=tuple(range(5)), budgets=(200,), fine_intervals=1000, name="optimality")
    job = Job(contender, case, 200, suite.seeds, 20.0, False)
    return [JobResult(job, metrics=metrics)], suite, [contender], relative


def test_every_table_reports_the_share_of_exact_seeds_beside_the_median():
    results, suite, contenders, relative = split_results()
    share = np.count_nonzero(relative <= 1e-9) / relative.size  # 3 of 5: the median alone says "exact"
    assert share == 0.6 and quantiles(relative)[0] <= 1e-9
    headline = headline_table(results, suite, contenders).splitlines()
    assert headline[0].endswith("| exact ≤ 1e-09 |") and headline[2].endswith("| 60% |")
    optimality = optimality_table(results, suite, contenders).splitlines()
    header = [c.strip() for c in optimality[0].strip("|").split("|")]
    row = [c.strip() for c in optimality[2].strip("|").split("|")]
    assert row[header.index("exact ≤ 1e-09")] == "60%"
    assert case_table(results, suite, contenders).splitlines()[2].split("|")[3].strip().endswith("· 60% exact")
    assert "(60% exact)" in realism_table(results, suite, contenders)
    assert aggregate(results)[0]["exact_1e-9"] == share
    assert exact_share(np.array([np.nan, np.inf, 1e-9, 2e-9])) == pytest.approx(1 / 3)  # NaN: n/a; inf: not exact
