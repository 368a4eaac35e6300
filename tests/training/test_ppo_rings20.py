"""The shipped ``ppo_rings20`` policy: the project's own PPO (``fxc train --backend torch``) from scratch on rings20-v2.

Goal (fxc_env/pretrained/README.md, "ppo_rings20"): no teacher, no ``--init-from``, the task's own
``plan_balanced`` actions (not ``residual``), one command of at most 30 minutes on 2 cores; loaded by name, its
median ``D(T_s)/D(0)`` on the task's 20 evaluation seeds is below the reference's (about 0.2 there).
"""

from __future__ import annotations

import csv
import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import torch

import fxc_env
from fxc_env import cli
from fxc_env.baselines.jobs import Job, run_job
from fxc_env.baselines.suite import builtin_contenders, learned_contender
from fxc_env.config.tasks import TASKS
from fxc_env.policies.learned import load_learned_policy, pretrained_path
from fxc_env.policies.torch_policy import TorchPolicy
from fxc_env.training.evaluate import task_suite

ROOT = Path(__file__).resolve().parents[2]
TASK = TASKS["rings20-v2"]


def recipe() -> list[str]:
    """The README's command for ``ppo_rings20``, as the arguments after ``fxc``."""
    text = (ROOT / "fxc_env" / "pretrained" / "README.md").read_text()
    commands = re.findall(r"`\.venv/bin/fxc (train --backend torch --task rings20-v2 [^`]*)`", text)
    assert len(commands) == 1, commands
    return shlex.split(commands[0])


def with_value(argv: list[str], flag: str, value: str) -> list[str]:
    """``argv`` with ``flag``'s value replaced by ``value``."""
    at = argv.index(flag) + 1
    return [*argv[:at], value, *argv[at + 1 :]]


def task_medians(seeds: tuple[int, ...]) -> tuple[float, float]:
    """Median D(T_s)/D(0) of ``ppo_rings20`` and of the reference on rings20-v2's episodes of ``seeds``."""
    suite, learned = task_suite(TASK)
    medians = []
    for contender in (learned_contender("ppo_rings20", **learned), builtin_contenders(["reference"])[0]):
        job = Job(contender, suite.cases[0], TASK.n_intervals, seeds, suite.settling_time, False)
        result = run_job(job)
        assert result.error is None, result.error
        medians.append(float(np.median(result.metrics["relative_deadline_error"])))
    return medians[0], medians[1]


def test_ppo_rings20_loads_by_name_and_beats_the_reference_on_five_evaluation_seeds():
    assert isinstance(load_learned_policy("ppo_rings20", fxc_env.parallel_env(**TASK.kwargs())), TorchPolicy)
    ours, reference = task_medians(TASK.eval_seeds[:5])
    assert 0.05 < reference < 0.5  # the reference's residual at K = 50 (about 0.2 over all 20 seeds)
    assert ours < reference


@pytest.mark.slow
def test_fxc_evaluate_scores_ppo_rings20_below_the_reference_on_the_tasks_20_seeds(tmp_path):
    argv = ["evaluate", "--task", "rings20-v2", "--policy", "ppo_rings20", "--out", str(tmp_path)]
    assert cli.main([*argv, "--no-progress", "--workers", "1"]) == 0
    rows = {row["policy"]: row for row in csv.DictReader((tmp_path / "results.csv").open())}
    assert {int(row["n_episodes"]) for row in rows.values()} == {20}
    ours = float(rows["learned:ppo_rings20"]["relative_deadline_error_median"])
    reference = float(rows["reference"]["relative_deadline_error_median"])
    assert ours < reference < 0.25  # the reference: 0.199


def test_the_readme_command_trains_the_shipped_network_from_scratch_on_the_task(tmp_path):
    """A rollout of the README's command: the task's environment, the file's settings, no teacher, the same network."""
    argv = recipe()
    assert "--init-from" not in argv and "--task" in argv
    shipped = torch.load(pretrained_path("ppo_rings20"), weights_only=True)
    assert shipped["timesteps"] == int(argv[argv.index("--timesteps") + 1])  # the file is the command's whole run
    argv = with_value(argv, "--hyperparams", str(ROOT / argv[argv.index("--hyperparams") + 1]))
    argv = with_value(with_value(argv, "--timesteps", "64000"), "--run-dir", str(tmp_path / "run"))  # one rollout
    assert cli.main([*argv, "--no-progress-bar"]) == 0
    record = json.loads((tmp_path / "run" / "config.json").read_text())
    assert record["args"]["task"] == "rings20-v2" and record["args"]["init_from"] is None
    assert record["torch_ppo"]["learning_rate"] == 1.0e-3 and record["torch_ppo"]["rollout_steps"] == 50
    assert record["hyperparams"]["env"]["action_mode"] == "plan_balanced"  # not residual: the task's own actions
    trained = torch.load(tmp_path / "run" / "policy.pt", weights_only=True)
    for key in ("format", "arch", "hidden", "activation", "obs_size", "action_size", "action_bound", "env", "domain"):
        assert trained[key] == shipped[key], key
    assert {k: v.shape for k, v in trained["actor"].items()} == {k: v.shape for k, v in shipped["actor"].items()}
    assert trained["timesteps"] == 64000
