"""What ``fxc leaderboard`` says about learning: the zero-action and random rows, each algorithm at 0 frames beside
its trained self, its learning curve and its cost (training faked here: BenchMARL's own runs are in
tests/benchmarl/test_leaderboard.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fxc_env.analysis.conditioning import final_ratios
from fxc_env.cli.main import main
from fxc_env.config.tasks import TASKS
from fxc_env.training.evaluation import leaderboard
from fxc_env.training.evaluation.leaderboard_files import result_record
from fxc_env.training.evaluation.leaderboard_runs import untrained_rows

TASK = TASKS["rings20-v2"]
EPISODES = len(TASK.eval_seeds)


def _fake_training(task, algorithm, seed, frames, folder):
    """A run as ``train_and_score`` records it: a curve from 100 down to 0.1 (seed-dependent) in three points."""
    points = [(0, 100.0 + seed), (frames // 2, 1.0), (frames, 0.1 * (seed + 1))]
    curve = [{"frames": f, "deadline_error": [e] * EPISODES, "energy": [2.0] * EPISODES} for f, e in points]
    return {**result_record(task), "algorithm": algorithm, "seed": seed, "frames": frames,
            "deadline_error": curve[-1]["deadline_error"], "energy": curve[-1]["energy"], "curve": curve,
            "seconds": {"collection": 1.0, "update": 3.0, "evaluation": 0.5, "wall": 4.6},
            "frames_per_second": frames / 4.0}  # fmt: skip


def _fake_laws(task, folder):
    names = leaderboard.scored_names()
    scores = {name: {"deadline_error": [0.2] * EPISODES, "energy": [2.0] * EPISODES} for name in names}
    scores.update(untrained_rows(task))
    return {**result_record(task), "contenders": names, "scores": scores}


def test_the_zero_and_random_rows_are_the_documented_floors_of_the_task():
    """rings20-v2's page: standing still 1.78, uniform random actions over the box 2.75e+07 (median, eval seeds)."""
    rows = untrained_rows(TASK)
    zero = np.median(rows["zero"]["deadline_error"])
    assert f"{zero:.3g}" == "1.78"
    np.testing.assert_allclose(
        rows["zero"]["deadline_error"], final_ratios(TASK.settings, "zero", None, TASK.eval_seeds)
    )
    assert np.median(rows["random"]["deadline_error"]) > 1e6
    assert untrained_rows(TASK)["random"] == rows["random"]  # seeded: the same row every time


def test_the_table_puts_each_algorithm_at_0_frames_beside_its_trained_self_with_its_cost_and_curve(
    tmp_path, monkeypatch
):
    monkeypatch.setattr(leaderboard, "has_benchmarl", lambda: True)
    monkeypatch.setattr(leaderboard, "train_and_score", _fake_training)
    monkeypatch.setattr(leaderboard, "score_laws", _fake_laws)
    argv = ["leaderboard", "--tasks", "rings20-v2", "--algorithms", "mappo", "ippo", "--frames", "3200"]
    assert main([*argv, "--seeds", "2", "--bootstrap-reps", "50", "--out", str(tmp_path)]) == 0
    table = (tmp_path / "table.md").read_text()
    rows = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines() if line.startswith("| ")}
    assert {"mappo", "ippo", "mappo@0", "ippo@0", "zero", "random", "reference"} <= set(rows)
    assert rows["mappo@0"].split(" | ")[1].startswith("100 ")  # the median of the curves' first points (100, 101)
    assert "| rings20-v2 | mappo | 3200 | 1.0 | 3.0 | 75% | 800 | 4.6 |" in table  # the cost table
    assert "; mappo@0 100; zero 1.78" in table  # the headline: against its 0-frame self and standing still
    assert (tmp_path / "curves_rings20-v2.png").stat().st_size > 0
    marl_eval = json.loads((tmp_path / "marl_eval.json").read_text())["fxc_env"]["rings20-v2"]
    assert marl_eval["ippo@0"]["seed_1"]["absolute_metrics"]["deadline_error"] == [101.0] * EPISODES


def test_the_shipped_v2_table_lists_every_v2_task_with_each_algorithm_beside_its_untrained_self():
    """fxc_env/assets/leaderboard-v2: MAPPO, IPPO, MASAC and MADDPG x 3 training seeds on every v2 task, each run's
    curve from 0 frames to its budget, and the zero, random and reference rows (its RUN.md: the command)."""
    shipped = Path(__file__).resolve().parents[2] / "fxc_env" / "assets" / "leaderboard-v2"
    runs = json.loads((shipped / "marl_eval.json").read_text())["fxc_env"]
    v2 = [task.id for task in TASKS.values() if task.version == 2]
    assert sorted(runs) == sorted(v2)
    for task in v2:
        for name in ("mappo", "ippo", "masac", "maddpg", "mappo@0", "ippo@0", "masac@0", "maddpg@0"):
            assert sorted(runs[task][name]) == ["seed_0", "seed_1", "seed_2"]
        assert {"zero", "random", "reference"} <= set(runs[task])
        assert (shipped / f"curves_{task}.png").stat().st_size > 0
    table = (shipped / "table.md").read_text()
    assert "Command: `fxc leaderboard --tasks rings20-v2 paper_fig1-v2 generalist-v2 saturated-v2" in table
    assert "| rings20-v2 | mappo | 1024000 |" in table  # the cost table: every run at its budget in the command
    assert "| rings20-v2 | masac | 64000 |" in table


def test_the_shipped_v2_table_has_mappo_and_ippo_3x_below_the_reference_and_their_untrained_selves_on_rings20():
    """The learning goal on rings20-v2 (README, results.md "BenchMARL on the v2 tasks"): the median D(T_s)/D(0) over
    3 training seeds x 20 evaluation episodes of MAPPO and IPPO at least 3x below the paper's law and below a third
    of their own 0-frame score; every algorithm of a kind trained on the same budget."""
    shipped = Path(__file__).resolve().parents[2] / "fxc_env" / "assets" / "leaderboard-v2"
    runs = json.loads((shipped / "marl_eval.json").read_text())["fxc_env"]["rings20-v2"]

    def median(name: str) -> float:
        return float(np.median([run["absolute_metrics"]["deadline_error"] for run in runs[name].values()]))

    reference = median("reference")
    for algorithm in ("mappo", "ippo"):
        assert median(algorithm) <= reference / 3
        assert median(algorithm) <= median(f"{algorithm}@0") / 3


def test_the_shipped_v2_table_has_mappo_and_ippo_within_a_decade_of_the_reference_on_every_v2_task():
    """The goal on every v2 task (README, results.md "BenchMARL on the v2 tasks"; generalist-v2 with its own reward
    floor, GAE lambda and rate, "IPPO on generalist-v2"): the median D(T_s)/D(0) over 3 training seeds x 20
    evaluation episodes of MAPPO and IPPO at most 10x the paper's law's."""
    shipped = Path(__file__).resolve().parents[2] / "fxc_env" / "assets" / "leaderboard-v2"
    runs = json.loads((shipped / "marl_eval.json").read_text())["fxc_env"]
    for task, board in runs.items():
        medians = {
            name: float(np.median([run["absolute_metrics"]["deadline_error"] for run in board[name].values()]))
            for name in ("reference", "mappo", "ippo")
        }
        assert max(medians["mappo"], medians["ippo"]) <= 10 * medians["reference"], (task, medians)
