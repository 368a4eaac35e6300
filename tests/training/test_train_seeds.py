"""fxc_env.training.evaluation.seeds and seed_evaluation: ``fxc train --seeds`` and ``fxc evaluate --runs``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fxc_env.cli import main
from fxc_env.core.validation import ArgumentError
from fxc_env.training import TrainArgs
from fxc_env.training.args import check_train_args
from fxc_env.training.evaluation.seed_evaluation import expand_runs, resolve_run
from fxc_env.training.evaluation.seeds import parse_seeds, plan_seed_runs, seed_run_dir


@pytest.mark.parametrize(
    ("text", "seeds"),
    [("0-4", (0, 1, 2, 3, 4)), ("0,2,5", (0, 2, 5)), ("0-2,7", (0, 1, 2, 7)), (" 3 ", (3,)), ("9-9", (9,))],
)
def test_seeds_are_ranges_and_lists(text, seeds):
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "--seeds: expected seeds such as '0-4' or '0,2,5', got ''"),
        ("a", "--seeds: expected seeds such as '0-4' or '0,2,5' (integers >= 0), got 'a'"),
        ("-1", "--seeds: expected seeds such as '0-4' or '0,2,5' (integers >= 0), got '-1'"),
        ("1.5", "--seeds: expected seeds such as '0-4' or '0,2,5' (integers >= 0), got '1.5'"),
        ("0,,2", "--seeds: expected seeds such as '0-4' or '0,2,5' (integers >= 0), got '0,,2'"),
        ("4-2", "--seeds: the range '4-2' ends below its start"),
        ("1,0-2", "--seeds: seed 1 is named twice in '1,0-2'"),
        ("4294967296", "--seeds: seeds are integers in [0, 2**32), got 4294967296"),
        ("0-5000", "--seeds: at most 1000 seeds (each is a training run), got more in '0-5000'"),
    ],
)
def test_bad_seeds_are_refused_by_name(text, message):
    with pytest.raises(ArgumentError) as caught:
        parse_seeds(text)
    assert str(caught.value) == message


@pytest.mark.parametrize("seed", ["0", "3"])
def test_seed_and_seeds_together_are_one_line_errors(tmp_path, capsys, seed):
    # Even --seed 0, the default, is refused: the command line says two different things.
    status = main(["train", "--seed", seed, "--seeds", "0-2", "--run-dir", str(tmp_path / "run")])
    assert status == 2
    assert (
        capsys.readouterr().err == "fxc train: error: --seeds: give one seed (--seed) or several (--seeds), not both\n"
    )
    assert not list(tmp_path.iterdir())


def test_a_bad_seed_list_or_a_bad_flag_stops_the_sweep_before_any_seed_trains(tmp_path, capsys):
    assert main(["train", "--seeds", "2-1", "--run-dir", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == "fxc train: error: --seeds: the range '2-1' ends below its start\n"
    assert main(["train", "--seeds", "0-1", "--timesteps", "0", "--run-dir", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == "fxc train: error: --timesteps: expected an integer >= 1, got 0\n"
    assert not list(tmp_path.iterdir())


def test_seeds_run_in_turn_so_a_ray_flag_is_refused_by_name(capsys):
    with pytest.raises(SystemExit) as caught:
        main(["train", "--seeds", "0-2", "--ray"])
    assert caught.value.code == 2
    assert "unrecognized arguments: --ray" in capsys.readouterr().err


def test_one_run_refuses_a_seed_list_instead_of_ignoring_it(tmp_path):
    with pytest.raises(ArgumentError, match=r"^seeds: one run trains one seed"):
        check_train_args(TrainArgs(seeds="0-2", run_dir=str(tmp_path / "run")))


def test_each_seed_has_its_own_run_directory():
    assert seed_run_dir(TrainArgs(run_dir="runs/gen"), 3) == "runs/gen-seed3"
    assert seed_run_dir(TrainArgs(scenario="ring_6"), 3) == "runs/ring_6-ppo-seed3"
    assert seed_run_dir(TrainArgs(backend="torch"), 1) == "runs/paper_fig1-torch-ppo-seed1"


def _checkpoint(run: Path, steps: int) -> None:
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / f"model_{steps}_steps.zip").write_bytes(b"")


def test_resume_goes_on_per_directory(tmp_path):
    base = tmp_path / "gen"
    _checkpoint(Path(f"{base}-seed0"), 1000)  # reached the target
    _checkpoint(Path(f"{base}-seed1"), 400)  # interrupted
    args = TrainArgs(seeds="0-2", run_dir=str(base), timesteps=1000, resume=True, n_envs=1)
    plan = plan_seed_runs(args)
    assert [(p.args.seed, p.action) for p in plan] == [(0, "done"), (1, "resume"), (2, "train")]
    assert [p.args.run_dir for p in plan] == [f"{base}-seed{k}" for k in range(3)]
    assert [p.args.resume for p in plan] == [True, True, False]
    assert plan[0].note == "already at 1000 timesteps (model_1000_steps.zip)"
    assert plan[2].note == "no checkpoint yet, so it starts afresh"
    # Without --resume every seed trains afresh.
    fresh = plan_seed_runs(TrainArgs(seeds="0-2", run_dir=str(base), timesteps=1000, n_envs=1))
    assert [p.action for p in fresh] == ["train"] * 3


def test_runs_are_found_by_glob_or_parent_folder_in_seed_order(tmp_path):
    for k in (10, 2, 1):
        (tmp_path / f"gen-seed{k}").mkdir()
        (tmp_path / f"gen-seed{k}" / "config.json").write_text(json.dumps({"args": {"seed": k, "timesteps": 5}}))
    expected = [str(tmp_path / f"gen-seed{k}") for k in (1, 2, 10)]
    assert expand_runs([str(tmp_path)]) == expected
    assert expand_runs([str(tmp_path / "gen-seed*")]) == expected
    assert [resolve_run(e).seed for e in expected] == [1, 2, 10]
    assert resolve_run("generalist").seed == 0  # the shipped policies' recipe: --seed 0
    with pytest.raises(ArgumentError, match="--runs: no run matches"):
        expand_runs([str(tmp_path / "nothing-*")])
    with pytest.raises(ArgumentError, match="is named twice"):
        expand_runs([expected[0], str(tmp_path / "gen-seed*")])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ArgumentError, match="is neither a run directory"):
        expand_runs([str(tmp_path / "empty")])


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:You have specified a mini-batch size")  # one tiny rollout
def test_several_seeds_train_resume_and_evaluate_with_intervals_and_marl_eval_json(tmp_path, capsys):
    base = tmp_path / "runs" / "pf"
    tiny = ["--scenario", "paper_fig1", "--n-envs", "1", "--timesteps", "1200", "--no-progress-bar"]
    assert main(["train", *tiny, "--seeds", "0-1", "--run-dir", str(base)]) == 0
    # A longer sweep with --resume leaves finished seeds and starts the new one.
    assert main(["train", *tiny, "--seeds", "0-2", "--run-dir", str(base), "--resume"]) == 0
    out = capsys.readouterr().out
    assert "seed 0 (1 of 3) in " + f"{base}-seed0: already at 1200 timesteps" in out
    assert "seed 2 (3 of 3) in " + f"{base}-seed2: no checkpoint yet, so it starts afresh" in out
    for k in range(3):
        assert json.loads(Path(f"{base}-seed{k}/config.json").read_text())["args"]["seed"] == k

    evaluate = ["evaluate", "--runs", str(tmp_path / "runs"), "--scenario", "paper_fig1", "--seeds", "3"]
    evaluate += ["--workers", "1", "--no-progress", "--bootstrap-reps", "300", "--out", str(tmp_path / "ev")]
    assert main(evaluate) == 0
    assert "pf over training seeds 0, 1, 2 (95% stratified bootstrap)" in capsys.readouterr().out

    record = json.loads((tmp_path / "ev" / "marl_eval.json").read_text())
    assert list(record) == ["fxc_env"]
    (task,) = record["fxc_env"].values()
    assert list(task) == ["pf", "reference"]
    for algorithm in task.values():
        assert list(algorithm) == ["seed_0", "seed_1", "seed_2"]
        for run in algorithm.values():
            assert list(run) == ["step_0", "absolute_metrics"]  # marl-eval reads the last key as absolute
            assert set(run["step_0"]) == {"step_count", "deadline_error", "decades_reached", "energy"}
            assert all(len(v) == 3 for k, v in run["absolute_metrics"].items())
    assert task["pf"]["seed_1"]["step_0"]["step_count"] == 1200
    assert task["reference"]["seed_0"] == task["reference"]["seed_2"]  # one law, the same episodes

    summary = json.loads((tmp_path / "ev" / "seeds.json").read_text())
    (case,) = summary["cases"]
    pooled = np.concatenate([run["absolute_metrics"]["deadline_error"] for run in task["pf"].values()])
    median = case["learned"]["median_deadline_error"]
    assert median["estimate"] == pytest.approx(np.median(pooled))
    assert median["low"] <= median["estimate"] <= median["high"]
    assert summary["bootstrap"] == {"reps": 300, "seed": 0, "confidence": 0.95, "log_floor": 1e-12}
    table = (tmp_path / "ev" / "seeds.md").read_text()
    assert "| paper_fig1 N=6 |" in table and "95% CI" in table


def test_evaluate_takes_one_policy_or_the_seeds_of_one(tmp_path, capsys):
    out = ["--out", str(tmp_path / "ev")]
    either = "fxc evaluate: error: --policy: give one policy (--policy) or the training seeds of one (--runs)\n"
    assert main(["evaluate", *out]) == 2
    assert capsys.readouterr().err == either
    assert main(["evaluate", "--policy", "reference", "--runs", "generalist", *out]) == 2
    assert capsys.readouterr().err == either
    assert main(["evaluate", "--policy", "reference", "--bootstrap-reps", "50", *out]) == 2
    assert capsys.readouterr().err == (
        "fxc evaluate: error: --bootstrap-reps: only --runs reads it (several training seeds), not --policy\n"
    )
    assert main(["evaluate", "--runs", "generalist", "--bootstrap-reps", "0", *out]) == 2
    assert "--bootstrap-reps: expected an integer >= 1" in capsys.readouterr().err
    for name in ("a-seed1", "b-seed1"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "config.json").write_text(json.dumps({"args": {"seed": 1}}))
    assert main(["evaluate", "--runs", str(tmp_path / "a-seed1"), str(tmp_path / "b-seed1"), *out]) == 2
    assert "were both trained with seed 1" in capsys.readouterr().err
    assert not (tmp_path / "ev").exists()


def test_runs_pooled_as_seeds_must_be_one_policy_and_non_policy_files_are_not_runs(tmp_path, capsys):
    from fxc_env.policies.learned import pretrained_path
    from fxc_env.training.evaluation.seed_evaluation import seed_contenders

    def copy(name, target):
        (tmp_path / target).write_bytes(pretrained_path(name).read_bytes())
        return str(tmp_path / target)

    # An SB3 generalist and a torch rings_gru are not two seeds of one policy; nor are two SB3 networks.
    for first, second, differs in [
        (("generalist", "x-seed0.zip"), ("rings_gru", "x-seed1.pt"), "format 'an SB3 model' vs 'a torch policy"),
        (("generalist", "y-seed0.zip"), ("paper_fig1", "y-seed1.zip"), "architecture 'the gain-scheduled network"),
    ]:
        runs = [resolve_run(entry) for entry in expand_runs([copy(*first), copy(*second)])]
        with pytest.raises(ArgumentError, match=rf"^--runs: .* are not training seeds of one policy: {differs}"):
            seed_contenders(runs, "x")

    # A glob that also catches a log skips it with a note; a log named by itself is refused by name.
    zips = [copy("generalist", f"g-seed{k}.zip") for k in (0, 1)]
    (tmp_path / "g-seed0.log").write_text("training log\n")
    assert expand_runs([str(tmp_path / "g-seed*")]) == zips
    assert [c.name for c in seed_contenders([resolve_run(z) for z in zips], "g")] == [
        "learned:g-seed0",
        "learned:g-seed1",
    ]
    assert f"--runs: skipping {str(tmp_path / 'g-seed0.log')!r}" in capsys.readouterr().err
    with pytest.raises(ArgumentError, match=r"^--runs: '.*g-seed0.log' is neither a saved policy \(.zip, .pt, .npz\)"):
        expand_runs([str(tmp_path / "g-seed0.log")])

    # A damaged config.json seed is refused by name, not taken as a seed.
    for seed in (-1, True, 2**70):
        run = tmp_path / "r-seed1"
        run.mkdir(exist_ok=True)
        (run / "config.json").write_text(json.dumps({"args": {"seed": seed}}))
        with pytest.raises(ArgumentError, match=r"^--runs: the seed in '.*r-seed1/config.json': expected an integer"):
            resolve_run(str(run))


def test_a_torch_ppo_run_and_an_analytic_gradient_run_are_not_pooled_as_seeds_of_one_policy(tmp_path):
    """Both save a torch policy file: the back end their run directories record is what tells them apart."""
    from fxc_env.policies.learned import pretrained_path
    from fxc_env.training.evaluation.seed_evaluation import seed_contenders

    for seed, backend, algo in ((0, "torch", "ppo"), (1, "diff", "apg")):
        run = tmp_path / f"rings-seed{seed}"
        run.mkdir()
        (run / "policy.pt").write_bytes(pretrained_path("rings_gru").read_bytes())
        (run / "config.json").write_text(json.dumps({"args": {"seed": seed, "backend": backend, "algo": algo}}))
    runs = [resolve_run(entry) for entry in expand_runs([str(tmp_path)])]
    assert [run.trainer for run in runs] == ["--backend torch --algo ppo", "--backend diff --algo apg"]
    with pytest.raises(
        ArgumentError,
        match=r"^--runs: .* are not training seeds of one policy: trainer '--backend torch --algo ppo' vs "
        r"'--backend diff --algo apg'",
    ):
        seed_contenders(runs, "rings")
    # Two torch PPO runs of it pool.
    config = json.loads((tmp_path / "rings-seed1" / "config.json").read_text())
    config["args"].update(backend="torch", algo="ppo")
    (tmp_path / "rings-seed1" / "config.json").write_text(json.dumps(config))
    runs = [resolve_run(entry) for entry in expand_runs([str(tmp_path)])]
    assert [c.name for c in seed_contenders(runs, "rings")] == ["learned:rings-seed0", "learned:rings-seed1"]
