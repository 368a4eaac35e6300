"""``fxc train --task NAME``: every back end trains on the named task's environment, and its run directory says so.

A few seconds of training each: what they can show is that the run records the task and that the
environment it trained on is the task's as ``fxc evaluate --task`` scores it (docs: training.md).
"""

from __future__ import annotations

import json

import pytest

from fxc_env.cli.main import main
from fxc_env.config.tasks import TASKS
from fxc_env.core.validation import ArgumentError
from fxc_env.training import TrainArgs
from fxc_env.training.args import check_train_args, default_run_dir

#: The environment a rings20-v2 run trains on: the task's settings, initial states drawn per episode.
RINGS20_V2_ENV = {"scenario": None, **TASKS["rings20-v2"].settings, "initial_state": "random"}


def _train(tmp_path, backend: str, *flags: str) -> dict:
    run_dir = tmp_path / "run"
    argv = ["train", "--backend", backend, "--task", "rings20-v2", "--run-dir", str(run_dir), "--no-progress-bar"]
    assert main([*argv, *flags]) == 0
    return json.loads((run_dir / "config.json").read_text())


def _assert_trained_on_the_task(record: dict) -> None:
    assert record["args"]["task"] == "rings20-v2"
    env = {key: value for key, value in record["hyperparams"]["env"].items() if key != "n_envs"}
    assert env == RINGS20_V2_ENV


def test_sb3_trains_on_the_task(tmp_path):
    record = _train(tmp_path, "sb3", "--n-envs", "1", "--timesteps", "1000")
    _assert_trained_on_the_task(record)
    assert record["num_envs"] == 20  # one episode of the ring's 20 agents


def test_torch_ppo_trains_on_the_task(tmp_path):
    record = _train(tmp_path, "torch", "--n-envs", "2", "--timesteps", "8000")
    _assert_trained_on_the_task(record)


def test_analytic_gradients_train_on_the_task(tmp_path):
    record = _train(tmp_path, "diff", "--n-envs", "2", "--timesteps", "2000")
    _assert_trained_on_the_task(record)


@pytest.mark.parametrize(("first", "then"), [(["--task", "rings20-v2"], []), ([], ["--task", "rings20-v2"])])
def test_resume_keeps_the_task_the_run_started_with(first, then, tmp_path, capsys):
    run = ["train", "--backend", "torch", "--n-envs", "1", "--run-dir", str(tmp_path / "run"), "--no-progress-bar"]
    assert main([*run, *first, "--timesteps", "1", "--checkpoint-every", "1"]) == 0
    assert main([*run, *then, "--timesteps", "100000", "--resume"]) == 2
    assert "task: the run in" in capsys.readouterr().err


def test_a_task_run_is_named_after_the_task_and_reads_the_tasks_hyperparameters():
    params = check_train_args(TrainArgs(task="fxc/paper_fig1-v2", backend="torch"))
    assert params["env"] == {"n_envs": 16, "scenario": "paper_fig1", **dict(TASKS["paper_fig1-v2"].settings),
                             "initial_state": "random"}  # fmt: skip
    assert params["algo"]["rollout_steps"] == 50  # one whole episode of the task's K
    assert default_run_dir(TrainArgs(task="rings20-v2", backend="torch")) == "runs/rings20-v2-torch-ppo-seed0"


def test_a_task_without_an_entry_takes_its_scenarios_hyperparameters_but_not_its_env(tmp_path):
    path = tmp_path / "hyperparams.yml"
    path.write_text(
        "default: {env: {n_envs: 3}, ppo: {n_steps: 10}}\n"
        "paper_fig1: {env: {n_envs: 2, n_intervals: 200, obs_slots: 4}, ppo: {n_steps: 25}}\n"
    )
    params = check_train_args(TrainArgs(task="paper_fig1-v2", hyperparams=str(path)))
    assert params["algo"] == {"n_steps": 25}
    assert params["env"] == {"n_envs": 2, "scenario": "paper_fig1", **dict(TASKS["paper_fig1-v2"].settings),
                             "initial_state": "random"}  # fmt: skip
    assert check_train_args(TrainArgs(task="rings20-v2", hyperparams=str(path)))["algo"] == {"n_steps": 10}


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--task", "rings20-v2", "--scenario", "ring_6"], "--scenario: --task rings20-v2 sets the environment"),
        (["--task", "rings20-v2", "--scenario", "paper_fig1"], "--scenario: --task rings20-v2 sets the environment"),
        (["--task", "rings20"], "--task: a task name carries its version"),
        (["--task", "ring_6"], "--task: expected one of"),
    ],
)
def test_fxc_train_refuses_a_conflicting_or_unknown_task_by_name(flags, message, tmp_path, capsys):
    assert main(["train", *flags, "--run-dir", str(tmp_path / "run")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_a_task_entry_of_the_hyperparameter_file_may_not_change_the_tasks_environment(tmp_path):
    path = tmp_path / "hyperparams.yml"
    path.write_text("rings20-v2:\n  env: {n_envs: 2, n_intervals: 200}\n  ppo: {n_steps: 50}\n")
    with pytest.raises(ArgumentError, match=r"hyperparams: the env of 'rings20-v2' in .* sets n_intervals"):
        check_train_args(TrainArgs(task="rings20-v2", hyperparams=str(path)))
