"""``fxc benchmark``: the quick run end to end, and single jobs."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from PIL import Image

from fxc_env.baselines.harness.jobs import Job, make_jobs, run_job
from fxc_env.baselines.harness.suite import BASELINES, BenchmarkCase, builtin_contenders, learned_contender, quick_suite
from fxc_env.cli import main

FIGURES = ("deadline_vs_budget.png", "energy_vs_error.png", "disagreement_vs_time.png")


@pytest.mark.slow
def test_quick_run_writes_table_csv_and_plots_and_the_reference_meets_the_deadline(tmp_path, capsys):
    assert main(["benchmark", "--quick", "--out", str(tmp_path), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    for name in ("table.md", "results.csv", "episodes.csv", *FIGURES):
        assert (tmp_path / name).stat().st_size > 0, name
    for name in FIGURES:
        with Image.open(tmp_path / name) as image:
            assert image.format == "PNG" and image.size[0] > 400 and image.size[1] > 300

    with open(tmp_path / "results.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    reference = [
        r for r in rows if (r["policy"], r["case"], r["n_intervals"]) == ("reference", "paper_fig1 N=6", "200")
    ]
    assert len(reference) == 1
    assert float(reference[0]["relative_deadline_error_median"]) <= 1e-9
    assert float(reference[0]["relative_deadline_error_q75"]) <= 1e-9

    # The printed Markdown: the by-case row of paper_fig1 opens with the reference's median at K = 200.
    row = next(line for line in printed.splitlines() if line.startswith("| paper_fig1 N=6 |"))
    assert float(row.split("|")[2].split("[")[0]) <= 1e-9
    # ... and closes with the case's intervals bounds: radius 5 (any law) / 7 (laws using every root).
    assert "intervals bound: radius (any law) / all roots |" in printed and row.endswith("| 5 / 7 |")
    assert (tmp_path / "table.md").read_text().strip() in printed

    # Every policy ran every quick case with the settings and notes the benchmark table of docs: benchmark.md lists.
    suite = quick_suite()
    assert len(rows) == len(make_jobs(suite, builtin_contenders()))
    refusing = ("minimum_time", "signalling", "graph_agnostic", "bounded_steer", "filtering")
    assert all(r["error"] == "" for r in rows if r["policy"] not in refusing)
    # The filtering law is designed for one fixed graph and its blocks: refusals by name.
    assert all(
        r["error"].startswith(("topology:", "switching:", "n_intervals:"))
        for r in rows
        if r["error"] and r["policy"] == "filtering"
    )
    # The minimum-time law is designed for one fixed graph: it refuses the switching cases, by name.
    refused = {r["case"] for r in rows if r["error"] and r["policy"] == "minimum_time"}
    assert refused == {"paper_fig1 N=6", "random (switching) N=6", "random (switching) N=20"}
    assert all(r["error"].startswith("topology:") for r in rows if r["error"] and r["policy"] == "minimum_time")
    # The signalling law needs its agreement's intervals: it refuses too small a K, by name.
    assert all(r["error"].startswith("n_intervals:") for r in rows if r["error"] and r["policy"] == "signalling")
    # The graph-agnostic law needs one fixed graph and its listening window: refusals by name.
    agnostic = [r["error"] for r in rows if r["error"] and r["policy"] == "graph_agnostic"]
    assert all(e.startswith(("n_intervals:", "topology:")) for e in agnostic)
    # The bounded-steer law floods over one fixed strongly connected graph: refusals by name.
    bounded = [r["error"] for r in rows if r["error"] and r["policy"] == "bounded_steer"]
    assert all(e.startswith(("n_intervals:", "topology:", "switching:")) for e in bounded)
    names = ("linear_sampled", "linear", "finite_time", "prescribed_time", "saturation_aware", "minimum_time")
    for name in (*names, "leader_follower"):
        assert f"- **{name}** — settings:" in printed
    assert printed.count("Proven for:") == len(BASELINES) + 1  # every analytic law, and the reference
    assert "Parameters (range over the suite" in printed
    assert "unproven" in printed  # finite-time and prescribed-time on digraphs


def test_a_job_is_seeded_and_repeatable():
    contender = builtin_contenders(["linear_sampled"])[0]
    job = Job(contender, BenchmarkCase("random", 6, period=3), 25, (0, 1, 2), 20.0, True)
    first, second = run_job(job), run_job(job)
    for name, values in first.metrics.items():
        np.testing.assert_array_equal(values, second.metrics[name], err_msg=name)
    assert first.trace.shape == (26,) and first.trace[0] == 1.0
    assert first.metrics["sampling_instants"].tolist() == [25, 25, 25]


def test_every_policy_meets_the_same_initial_states():
    case, seeds = BenchmarkCase("ring", 6), (4, 5)
    initial = [
        run_job(Job(c, case, 25, seeds, 20.0, False)).metrics["initial_disagreement"] for c in builtin_contenders()
    ]
    for values in initial[1:]:
        np.testing.assert_array_equal(values, initial[0])


@pytest.mark.slow
def test_a_learned_policy_runs_as_a_contender_or_says_why_not():
    refused = run_job(Job(learned_contender("pretrained"), BenchmarkCase("paper_fig1", 6), 50, (0, 1), 20.0, False))
    assert "n_agents: trained on 20, this environment has 6" in refused.error  # the generalist's domain: N = 20
    contender = learned_contender("pretrained", allow_out_of_domain=True)
    ran = run_job(Job(contender, BenchmarkCase("paper_fig1", 6), 50, (0, 1), 20.0, False))
    assert ran.error is None and ran.guarantee.startswith("learned")
    assert np.all(np.isfinite(ran.metrics["relative_deadline_error"]))
    complete = run_job(Job(contender, BenchmarkCase("complete", 6), 50, (0, 1), 20.0, False))
    assert complete.error is None  # the gain network reads in-degree 5 too
    skipped = run_job(Job(learned_contender("paper_fig1"), BenchmarkCase("complete", 6), 50, (0, 1), 20.0, False))
    assert "obs_slots" in skipped.error  # in-degree 5 does not fit the MLP's 4 rows


@pytest.mark.slow
def test_realism_suite_reports_saturation_for_the_reference_under_an_input_limit(tmp_path):
    from dataclasses import replace

    from fxc_env.baselines.harness.benchmark import run_benchmark
    from fxc_env.baselines.harness.suite import realism_suite

    full = realism_suite(n_seeds=3, fine_intervals=200)
    assert {s.condition for s in full.cases} >= {"ideal", "u_max = 10", "obs_noise = 0.1", "link_dropout = 0.3"}
    suite = replace(full, cases=tuple(s for s in full.cases if s.condition in ("ideal", "u_max = 10")))
    output = run_benchmark(suite, builtin_contenders(["reference"]), tmp_path, workers=1, progress=False)
    rows = {r["case"]: r for r in csv.DictReader((tmp_path / "results.csv").open())}
    limited, ideal = rows["paper_fig1 N=6, u_max=10"], rows["paper_fig1 N=6"]
    assert float(limited["saturated_fraction_median"]) > 0 and float(ideal["saturated_fraction_median"]) == 0
    assert float(limited["peak_input_median"]) <= 10
    assert float(limited["relative_deadline_error_median"]) > float(ideal["relative_deadline_error_median"])
    assert "### Realism" in output.markdown and "| paper_fig1 N=6 | u_max = 10 |" in output.markdown


def test_a_realism_job_with_noise_and_dropout_is_seeded_and_repeatable():
    contender = builtin_contenders(["reference"])[0]
    conditions = (("obs_noise", 0.1), ("link_dropout", 0.3))
    case = BenchmarkCase("random", 8, period=3, conditions=conditions)
    job = Job(contender, case, 25, (0, 1, 2), 20.0, True)
    first, second = run_job(job), run_job(job)
    assert first.error is None
    for name, values in first.metrics.items():
        np.testing.assert_array_equal(values, second.metrics[name], err_msg=name)
    np.testing.assert_array_equal(first.trace, second.trace)
    # The noise matters (else this test proves nothing), and other seeds give other runs.
    ideal = run_job(Job(contender, BenchmarkCase("random", 8, period=3), 25, (0, 1, 2), 20.0, False))
    assert not np.array_equal(first.metrics["relative_deadline_error"], ideal.metrics["relative_deadline_error"])
    other = run_job(Job(contender, case, 25, (3, 4, 5), 20.0, False))
    assert not np.array_equal(first.metrics["relative_deadline_error"], other.metrics["relative_deadline_error"])


def test_a_damaged_saved_policy_is_an_argument_error_naming_policy(tmp_path):
    from fxc_env import make_config
    from fxc_env.baselines.harness.suite import load_policy
    from fxc_env.core.validation import ArgumentError

    config = make_config("paper_fig1", obs_slots=4)
    (tmp_path / "empty.zip").write_bytes(b"")
    (tmp_path / "text.zip").write_text("not a zip\n")
    for path in (tmp_path / "empty.zip", tmp_path / "text.zip"):
        with pytest.raises(ArgumentError, match=r"^policy: "):
            load_policy(str(path), config)
        with pytest.raises(ArgumentError, match=r"^policy: "):
            learned_contender(str(path))
        with pytest.raises(ArgumentError, match=r"^--policy: "):
            learned_contender(str(path), name="--policy")
    with pytest.raises(ArgumentError, match=r"^--policy: no saved model"):
        learned_contender(str(tmp_path / "missing.zip"), name="--policy")


@pytest.mark.slow
def test_the_optimality_suite_reports_every_law_against_e_star_and_the_intervals_bounds(tmp_path, capsys):
    argv = ["benchmark", "--suite", "optimality", "--quick", "--seeds", "2", "--out", str(tmp_path), "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "### How far from optimal" in printed
    with Image.open(tmp_path / "error_vs_energy_ratio.png") as image:
        assert image.format == "PNG" and image.size[0] > 400
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    by = {(r["policy"], r["case"]): r for r in rows}
    # Both schedules for the reference and the minimum-time law, the other analytic laws beside them.
    assert {"reference", "reference/uniform", "minimum_time", "minimum_time/paper", "linear", "finite_time"} <= {
        policy for policy, _ in by
    }
    ring = by[("minimum_time", "ring N=20")]
    assert float(ring["relative_deadline_error_q75"]) <= 1e-12
    assert float(ring["settled_interval_median"]) == float(ring["radius_bound_median"]) == 19
    assert float(ring["all_roots_bound_median"]) == 19  # a ring: every agent is a root, all 19 hops away
    assert "| radius bound | all-roots bound |" in printed
    assert by[("minimum_time/paper", "paper_fig1 N=6")]["error"].startswith("topology:")
    # E* bounds every episode that ends in exact consensus (episodes.csv: one row per episode).
    episodes = list(csv.DictReader((tmp_path / "episodes.csv").open()))
    exact = [e for e in episodes if float(e["relative_deadline_error"]) < 1e-9]
    assert len(exact) >= 10
    assert all(float(e["energy_ratio"]) >= 1.0 for e in exact)
    assert all(float(e["settled_interval"]) >= float(e["radius_bound"]) for e in exact)
