"""Medians with spread: quantiles, cells and the per-job CSV rows."""

from __future__ import annotations

import math

import numpy as np

from fxc_env.baselines.jobs import Job, JobResult
from fxc_env.baselines.report import CSV_METRICS, aggregate, quantiles, spread_cell
from fxc_env.baselines.suite import BenchmarkCase, builtin_contenders


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
