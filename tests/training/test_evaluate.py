"""fxc evaluate: a learned policy next to the reference on paper_fig1 and the N = 20 generalisation graphs."""

from __future__ import annotations

import csv

import pytest

from fxc_env import cli
from fxc_env.training.evaluation.evaluate import EVALUATION_CASES


@pytest.mark.slow
def test_evaluate_pretrained_prints_and_writes_the_comparison(tmp_path, capsys):
    argv = ["evaluate", "--policy", "pretrained", "--seeds", "3", "--out", str(tmp_path), "--no-progress"]
    code = cli.main([*argv, "--allow-out-of-domain"])  # paper_fig1 (N = 6): outside the generalist's N = 20
    out = capsys.readouterr().out
    assert code == 0
    assert "| reference | 200 |" in out and "| learned:generalist | 200 |" in out
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert {(r["policy"], r["case"]) for r in rows} == {
        (policy, case.key) for policy in ("reference", "learned:generalist") for case in EVALUATION_CASES
    }
    assert all(int(r["n_episodes"]) == 3 for r in rows)
    for name in ("table.md", "deadline_vs_budget.png", "energy_vs_error.png", "disagreement_vs_time.png"):
        assert (tmp_path / name).stat().st_size > 0


@pytest.mark.slow
def test_evaluate_reference_alone_and_bad_budgets(tmp_path, capsys):
    assert cli.main(["evaluate", "--policy", "reference", "--seeds", "2", "--out", str(tmp_path), "--no-progress"]) == 0
    assert "learned" not in capsys.readouterr().out
    assert cli.main(["evaluate", "--policy", "reference", "--budgets", "two hundred", "--out", str(tmp_path)]) == 2
    assert "--budgets" in capsys.readouterr().err


def test_budgets_are_comma_separated_distinct_positive_integers():
    import pytest

    from fxc_env.core.validation import ArgumentError
    from fxc_env.utils.cli_checks import budgets

    assert budgets("--budgets", "25, 200") == (25, 200)
    assert budgets("--budgets", "200") == (200,)
    for bad in ("0", "0,200", "abc", "", "25,", "200,200", "1e3", "-5", "2000000"):
        with pytest.raises(ArgumentError, match=r"^--budgets: "):
            budgets("--budgets", bad)


def test_evaluate_checks_everything_before_it_runs(tmp_path, capsys, monkeypatch):
    import fxc_env.training.evaluation.evaluate as evaluate

    def no_run(*args, **kwargs):
        raise AssertionError("the benchmark ran before the arguments were checked")

    monkeypatch.setattr(evaluate, "run_benchmark", no_run)
    (tmp_path / "model.zip").write_text("not a model\n")
    argv = ["evaluate", "--policy", str(tmp_path / "model.zip"), "--out", str(tmp_path / "out")]
    assert cli.main(argv) == 2
    assert capsys.readouterr().err.startswith("fxc evaluate: error: --policy: ")
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_evaluate_on_environment_flags_scores_that_one_environment(tmp_path, capsys):
    argv = ["evaluate", "--policy", "saturated", "--family", "ring", "--topology-period", "2,3", "--n-agents", "6"]
    argv += ["--u-max", "10,100", "--seeds", "2", "--out", str(tmp_path), "--no-progress"]
    assert cli.main(argv) == 0
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert {r["policy"] for r in rows} == {"reference", "learned:saturated"}
    assert {r["case"] for r in rows} == {"ring_m2-3 (drawn) N=6, u_max={10, 100}"}
    learned = next(r for r in rows if r["policy"] == "learned:saturated")
    assert learned["schedule"] == "uniform"  # the schedule the shipped policy was trained on


def test_evaluate_refuses_a_suite_and_environment_flags_together(tmp_path, capsys):
    argv = ["evaluate", "--policy", "reference", "--suite", "realism", "--n-agents", "8", "--out", str(tmp_path)]
    assert cli.main(argv) == 2
    assert "--suite" in capsys.readouterr().err


def test_a_policy_refused_on_every_case_is_a_usage_error(tmp_path, capsys, monkeypatch):
    from types import SimpleNamespace

    import fxc_env.training.evaluation.evaluate as evaluate

    def every_case_refused(suite, contenders, out, **kwargs):
        results = [
            SimpleNamespace(
                job=SimpleNamespace(contender=c), error=None if c.name == "reference" else "obs size 30, not 12"
            )
            for c in contenders
            for _ in suite.cases
        ]
        return SimpleNamespace(markdown="Not run", files=[], results=results)

    monkeypatch.setattr(evaluate, "run_benchmark", every_case_refused)
    argv = ["evaluate", "--policy", "saturated", "--seeds", "1", "--out", str(tmp_path / "out"), "--no-progress"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc evaluate: error: --policy: ") and "(obs size 30, not 12)" in err
    assert len(err.strip().splitlines()) == 1


def test_an_output_directory_that_cannot_be_created_is_a_usage_error(tmp_path, capsys):
    argv = ["evaluate", "--policy", "reference", "--seeds", "1", "--out", "/proc/fxc-evaluate/out", "--no-progress"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fxc evaluate: error: --out: ") and "/proc" in err


def test_environment_flags_carry_the_agent_model_into_the_case_and_refuse_formations():
    from fxc_env import make_config
    from fxc_env.training.evaluation.evaluate import custom_case

    case, settling_time = custom_case(
        {"scenario": "paper_fig1", "agent_model": {"name": "oscillator", "frequency": 1000.0}}
    )
    assert ("agent_model", "oscillator") in case.conditions and ("frequency", 1000.0) in case.conditions
    config = make_config(**case.config_kwargs(), n_intervals=200, settling_time=settling_time)
    assert config.agent_model == "oscillator" and config.model.A[1, 0] == -1e6  # omega^2 = 1e6
    plain, _ = custom_case({"scenario": "paper_fig1", "dim": 2})
    assert not any(name == "agent_model" for name, _ in plain.conditions)
    with pytest.raises(ValueError, match=r"--scenario: .*formation"):
        custom_case({"scenario": "formation_hexagon"})


def test_a_policy_named_twice_in_policies_is_refused_before_anything_runs(tmp_path, capsys, monkeypatch):
    import fxc_env.baselines.harness.benchmark as benchmark

    def no_run(*args, **kwargs):
        raise AssertionError("the benchmark ran before the arguments were checked")

    monkeypatch.setattr(benchmark, "run_benchmark", no_run)
    argv = ["benchmark", "--quick", "--no-progress", "--policies", "reference,reference", "--out", str(tmp_path / "b")]
    assert cli.main(argv) == 2
    assert capsys.readouterr().err == (
        "fxc benchmark: error: --policies: 'reference' is named twice in 'reference,reference'\n"
    )


def test_the_notes_state_the_initial_state_ranges_that_were_drawn(tmp_path, capsys):
    # The notes said "positions U(-5, 5) m" whatever --position-range drew.
    common = ["evaluate", "--policy", "reference", "--scenario", "paper_fig1", "--seeds", "1", "--no-progress"]
    assert cli.main([*common, "--out", str(tmp_path / "default")]) == 0
    assert "Initial states: positions U(-5, 5) m, velocities U(-2, 2) m/s," in capsys.readouterr().out
    ranges = ["--position-range", "0.5,50", "--velocity-range", "3"]
    assert cli.main([*common, *ranges, "--out", str(tmp_path / "ranges")]) == 0
    expected = "Initial states: positions U(-r, r) m, r log-uniform in [0.5, 50], velocities U(-3, 3) m/s,"
    assert expected in capsys.readouterr().out


def test_the_notes_name_the_learned_policys_format(tmp_path, capsys):
    # The notes called every saved policy that was neither a torch policy nor a directory an "SB3 model".
    argv = ["evaluate", "--policy", "rings", "--topology", "ring", "--n-agents", "20", "--seeds", "1"]
    assert cli.main([*argv, "--out", str(tmp_path), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "Law: a learned policy (gain schedule `" in out and "rings.npz`)" in out and "SB3 model" not in out


def test_a_task_that_fixes_its_schedule_scores_every_contender_on_it():
    """saturated-v1 is the uniform schedule: the reference is scored there, not on its own paper schedule
    (which put 0.358 in the table for an environment the task is not); a task without one leaves each its own."""
    from fxc_env.baselines.harness.suite import builtin_contenders
    from fxc_env.config.tasks import TASKS
    from fxc_env.training.evaluation.evaluate import on_task_schedule, task_suite

    contenders = builtin_contenders(["reference", "minimum_time"])
    assert [c.schedule for c in contenders] == ["paper", "uniform"]
    _, learned = task_suite(TASKS["saturated-v1"])
    assert [c.schedule for c in on_task_schedule(contenders, learned)] == ["uniform", "uniform"]
    _, learned = task_suite(TASKS["rings20-v1"])
    assert [c.schedule for c in on_task_schedule(contenders, learned)] == ["paper", "uniform"]
