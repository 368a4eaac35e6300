"""What ``fxc leaderboard`` keeps under ``--out``: every result records what it was scored for, a rerun keeps only
what matches (``laws.json`` is scored again, a training run refused, by name), and its ``marl_eval.json`` (the
shipped one too) is what marl-eval itself loads and plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fxc_env.cli.main import main
from fxc_env.config.tasks import TASKS
from fxc_env.core.validation import ArgumentError
from fxc_env.training.evaluation import leaderboard
from fxc_env.training.evaluation.leaderboard import ALGORITHMS, law_contenders, plan_files
from fxc_env.training.evaluation.leaderboard_files import marl_eval_record, result_record

SHIPPED = Path(__file__).resolve().parents[2] / "fxc_env" / "assets" / "leaderboard"
TASK = TASKS["rings20-v1"]
EPISODES = len(TASK.eval_seeds)
NONE = ["leaderboard", "--algorithms", "none", "--bootstrap-reps", "50"]
ONE = [*NONE, "--tasks", "rings20-v1"]


def _run(**changes):
    """A training run's file as ``fxc leaderboard`` writes it, with ``changes``."""
    record = {**result_record(TASK), "algorithm": "mappo", "seed": 0, "frames": 1000}
    record.update(deadline_error=[0.5] * EPISODES, energy=[1.0] * EPISODES)
    start = {"frames": 0, "deadline_error": [9.0] * EPISODES, "energy": [1.0] * EPISODES}
    record.update(curve=[start, {"frames": 1000, "deadline_error": [0.5] * EPISODES, "energy": [1.0] * EPISODES}])
    record.update(seconds={"collection": 1.0, "update": 3.0, "evaluation": 0.5, "wall": 4.6}, frames_per_second=250.0)
    return {**record, **changes}


def _fake_laws(calls):
    """A stand-in for scoring the laws (the real one takes half a minute): whole scores, its calls counted."""

    def score(task, folder):
        calls.append(task.id)
        names = leaderboard.scored_names()
        scores = {name: {"deadline_error": [1e-9] * EPISODES, "energy": [2.0] * EPISODES} for name in names}
        return {**result_record(task), "contenders": names, "scores": scores}

    return score


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"deadline_error": [1e-30] * EPISODES, "energy": [1.0] * EPISODES, "frames": 1000}, "records no task, seeds"),
        (_run(task="fxc/saturated-v1"), "records task 'fxc/saturated-v1', not 'fxc/rings20-v1'"),
        (_run(seeds=[0, 1]), "records seeds [0, 1], not [1000, 1001"),
        (_run(fxc_env="0.0.9"), "records fxc_env '0.0.9', not"),
        (_run(algorithm="ippo"), "records algorithm 'ippo', not 'mappo'"),
        (_run(deadline_error=[0.5] * (EPISODES - 1)), f"holds no {EPISODES} deadline_error values"),
        (_run(energy=[-1.0] * EPISODES), "holds a energy of -1.0"),
        (_run(frames="1000"), "records no frame budget"),
        ({k: v for k, v in _run().items() if k != "curve"}, "records no learning curve (written by an older"),
        (_run(curve=_run()["curve"][1:]), "holds a learning curve that does not start at 0 frames"),
        (_run(frames=2000), "holds a learning curve whose frames [0, 1000] do not rise to its 2000"),
        (_run(deadline_error=[0.4] * EPISODES), "holds scores other than its learning curve's last"),
        (_run(seconds={"wall": 4.0}), "records no seconds ('collection', 'update', 'evaluation', 'wall')"),
        (_run(frames_per_second=0), "records no frames_per_second"),
        ("{", "cannot be read as JSON (JSONDecodeError)"),
        ([1, 2], "holds a list, not a JSON object"),
    ],
)
def test_a_kept_training_run_that_is_hand_made_foreign_or_damaged_is_refused_by_name(tmp_path, change, why):
    path = tmp_path / "rings20-v1" / "mappo" / "seed0.json"
    path.parent.mkdir(parents=True)
    path.write_text(change if isinstance(change, str) else json.dumps(change))
    with pytest.raises(ArgumentError) as info:
        plan_files(tmp_path, [TASK], ["mappo"], 1, {"mappo": 1000}, [c.name for c in law_contenders()])
    message = str(info.value)
    assert message.startswith(f"--out: {path} {why}") and "delete it to train and score that run again" in message
    # A run recorded as fxc leaderboard writes it is kept; the other seed is still to train.
    path.write_text(json.dumps(_run()))
    rescore, train = plan_files(tmp_path, [TASK], ["mappo"], 2, {"mappo": 1000}, [c.name for c in law_contenders()])
    assert rescore == {"rings20-v1": ""} and train == [(TASK, "mappo", 1)]


@pytest.mark.parametrize(
    ("edit", "why"),
    [
        (lambda laws: {**laws, "task": "fxc/saturated-v1"}, "it records task 'fxc/saturated-v1', not"),
        (lambda laws: {**laws, "fxc_env": "0.0.9"}, "it records fxc_env '0.0.9', not"),
        (lambda laws: {k: v for k, v in laws.items() if k != "fxc_env"}, "it records no fxc_env"),
        (lambda laws: {**laws, "episodes": 19, "seeds": laws["seeds"][:19]}, "it records seeds"),
        (
            lambda laws: {
                **laws,
                "scores": {**laws["scores"], "reference": {"deadline_error": [1e-30], "energy": [1]}},
            },
            f"it holds no {EPISODES} deadline_error values for reference",
        ),
        (lambda laws: {**laws, "scores": {"reference": laws["scores"]["reference"]}}, "it holds no scores for every"),
        (lambda laws: "not json", "it cannot be read as JSON"),
    ],
)
def test_laws_json_that_does_not_match_is_scored_again_naming_the_file(tmp_path, capsys, monkeypatch, edit, why):
    calls = []
    monkeypatch.setattr(leaderboard, "score_laws", _fake_laws(calls))
    assert main([*ONE, "--out", str(tmp_path)]) == 0
    assert calls == ["rings20-v1"]
    capsys.readouterr()
    assert main([*ONE, "--out", str(tmp_path)]) == 0  # a matching file is kept
    assert calls == ["rings20-v1"] and "again" not in capsys.readouterr().out
    path = tmp_path / "rings20-v1" / "laws.json"
    laws = edit(json.loads(path.read_text()))
    path.write_text(laws if isinstance(laws, str) else json.dumps(laws))
    assert main([*ONE, "--out", str(tmp_path)]) == 0
    assert calls == ["rings20-v1"] * 2
    assert f"fxc leaderboard: scoring {path} again: {why}" in capsys.readouterr().out
    assert "1e-30" not in (tmp_path / "table.md").read_text()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "/proc/fxc-leaderboard/out"], "--out: cannot create '/proc/fxc-leaderboard/out/rings20-v1'"),
        (["--tasks", "rings20-v1", "fxc/rings20-v1"], "--tasks: rings20-v1 is named twice; name each task once"),
        (["--frames", "2000"], "--frames: only BenchMARL's algorithms read it, and --algorithms none trains nothing"),
        (["--seeds", "5"], "--seeds: only BenchMARL's algorithms read it"),
    ],
)
def test_bad_leaderboard_requests_are_one_line_errors_naming_the_flag(tmp_path, capsys, monkeypatch, argv, message):
    calls = []
    monkeypatch.setattr(leaderboard, "score_laws", _fake_laws(calls))
    argv = [*argv, *(() if "--tasks" in argv else ("--tasks", "rings20-v1"))]
    argv = [*argv, *(() if "--out" in argv else ("--out", str(tmp_path / "board")))]
    assert main([*NONE, *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fxc leaderboard: error: {message}") and err.count("\n") == 1
    assert calls == [] and not (tmp_path / "board").exists()  # refused before any work


@pytest.mark.parametrize(("flag", "value"), [("--frames", 10**9), ("--seeds", 101)])
def test_the_training_budget_is_bounded(flag, value):
    namespace = leaderboard.argparse.Namespace(frames=1000, seeds=3)
    setattr(namespace, flag[2:], value)
    with pytest.raises(ArgumentError, match=f"^{flag}: expected an integer"):
        leaderboard.check_budget(namespace, ["mappo"])


def test_frames_give_one_budget_then_one_per_algorithm_that_differs():
    namespace = leaderboard.argparse.Namespace(frames=["1024000", "masac=64000"], seeds=3)
    assert leaderboard.check_budget(namespace, ["mappo", "masac"]) == ({"mappo": 1024000, "masac": 64000}, 3)


@pytest.mark.parametrize("frames", [["1000", "maddpg=10"], ["1000", "masac"], ["1000", "masac=1", "masac=2"]])
def test_a_budget_for_an_algorithm_not_trained_or_named_twice_is_refused(frames):
    namespace = leaderboard.argparse.Namespace(frames=frames, seeds=3)
    with pytest.raises(ArgumentError, match=r"^--frames: after the budget, expected ALGORITHM=FRAMES"):
        leaderboard.check_budget(namespace, ["mappo", "masac"])


def test_every_algorithm_of_a_task_lists_the_same_runs_and_a_law_its_one_row_under_each():
    """marl-eval needs the same algorithms and runs in every task: a law (deterministic) repeats its row under
    every run key of the trained algorithms; a contender refused on a task is left out of the file."""
    errors = {"mappo": np.array([[1.0, 2.0], [3.0, 4.0], [5.0, np.inf]]), "reference": np.array([[1e-9, 2e-9]])}
    scores = {
        "mappo": {"a": errors["mappo"], "b": errors["mappo"]},
        "reference": {"a": errors["reference"], "b": errors["reference"]},
        "minimum_time": {"a": errors["reference"]},  # refused on b
    }
    record = marl_eval_record(scores, scores, ["a", "b"], 3)["fxc_env"]
    assert list(record) == ["a", "b"]
    for task in record.values():
        assert list(task) == ["mappo", "reference"]
        assert all(list(runs) == ["seed_0", "seed_1", "seed_2"] for runs in task.values())
        assert task["reference"]["seed_0"] == task["reference"]["seed_2"]
        assert task["mappo"]["seed_2"]["absolute_metrics"]["deadline_error"] == [5.0, np.inf]
    assert list(marl_eval_record(scores, scores, ["a"], 3)["fxc_env"]["a"]) == ["mappo", "reference", "minimum_time"]


def test_marl_eval_loads_and_plots_the_shipped_table(tmp_path, capsys):
    """The shipped ``marl_eval.json`` through marl-eval's own checks, loader and plots (id-marl-eval 0.0.4)."""
    import matplotlib

    matplotlib.use("Agg")
    from marl_eval.plotting_tools.plotting import plot_single_task
    from marl_eval.utils.data_processing_utils import create_matrices_for_rliable, data_process_pipeline
    from marl_eval.utils.diagnose_data_errors import DiagnoseData
    from matplotlib import pyplot

    raw = json.loads((SHIPPED / "marl_eval.json").read_text())
    checks = DiagnoseData(raw).check_data()
    assert all(checks["fxc_env"].values()), checks
    tasks = tuple(raw["fxc_env"])  # the shipped table's tasks (v1)
    metrics = ["decades_reached"]
    processed = data_process_pipeline(raw_data=raw, metrics_to_normalize=metrics)
    assert "extra" in processed  # marl-eval returns the raw data unprocessed when it cannot read it
    matrices, _ = create_matrices_for_rliable(processed, "fxc_env", metrics)
    by_algorithm = matrices["mean_norm_decades_reached"]
    assert set(by_algorithm) == {*ALGORITHMS, "reference"}  # the contenders every task scored
    assert all(matrix.shape == (3, len(tasks)) for matrix in by_algorithm.values())  # seeds x tasks
    for task in tasks:  # its per-task plot of every contender over its runs
        axes = plot_single_task(processed, "fxc_env", task, "decades_reached", metrics, xlabel="frames")
        axes.figure.savefig(tmp_path / f"{task}.png")  # marl-eval 0.0.4 returns the axes, not the figure
        pyplot.close(axes.figure)
    assert all((tmp_path / f"{task}.png").stat().st_size > 0 for task in tasks)


def test_on_a_task_the_shipped_policies_run_with_its_action_mode_and_the_laws_on_the_schedule_it_fixes():
    """rings20-v2's shipped PPO was refused in the v2 table ("trained with plan_balanced, this environment has
    plan"), and saturated's reference ran on its own paper schedule: a task is one environment for every row."""
    from fxc_env.training.evaluation.evaluate import task_suite

    _, learned = task_suite(TASKS["rings20-v2"])
    shipped = {c.name: c for c in law_contenders(learned)}
    assert shipped["learned:ppo_rings20"].action_mode == "plan_balanced"
    _, learned = task_suite(TASKS["saturated-v1"])
    assert {c.schedule for c in law_contenders(learned) if not c.name.startswith("learned:")} == {"uniform"}
