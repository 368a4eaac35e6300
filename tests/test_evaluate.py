"""fxc evaluate: a learned policy next to the reference on paper_fig1 and the N = 20 generalisation graphs."""

from __future__ import annotations

import csv

from fxc_env import cli
from fxc_env.training.evaluate import EVALUATION_SCENARIOS


def test_evaluate_pretrained_prints_and_writes_the_comparison(tmp_path, capsys):
    code = cli.main(["evaluate", "--policy", "pretrained", "--seeds", "3", "--out", str(tmp_path), "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0
    assert "| reference | 200 |" in out and "| learned:paper_fig1_ppo | 200 |" in out
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert {(r["policy"], r["scenario"]) for r in rows} == {
        (policy, scenario.key)
        for policy in ("reference", "learned:paper_fig1_ppo")
        for scenario in EVALUATION_SCENARIOS
    }
    assert all(int(r["n_episodes"]) == 3 for r in rows)
    for name in ("table.md", "deadline_vs_budget.png", "energy_vs_error.png", "disagreement_vs_time.png"):
        assert (tmp_path / name).stat().st_size > 0


def test_evaluate_reference_alone_and_bad_budgets(tmp_path, capsys):
    assert cli.main(["evaluate", "--policy", "reference", "--seeds", "2", "--out", str(tmp_path), "--no-progress"]) == 0
    assert "learned" not in capsys.readouterr().out
    assert cli.main(["evaluate", "--policy", "reference", "--budgets", "two hundred", "--out", str(tmp_path)]) == 2
    assert "--budgets" in capsys.readouterr().err
