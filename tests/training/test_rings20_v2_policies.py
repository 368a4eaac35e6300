"""The shipped ``ppo_rings20`` and ``diff_rings20`` policies: the project's own learners from scratch on rings20-v2.

Goals (fxc_env/pretrained/README.md, "ppo_rings20" and "diff_rings20"): no teacher, no ``--init-from``, the
task's own ``plan_balanced`` actions (not ``residual``), an MLP on the agent's own observation, one command of
at most 30 minutes on 2 cores each; loaded by name, the median ``D(T_s)/D(0)`` on the task's 20 evaluation
seeds is below the reference's (about 0.2 there) for ``fxc train --backend torch`` (PPO) and at least ten
times below it for ``fxc train --backend diff`` (analytic policy gradients).
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
import yaml

import fxc_env
from fxc_env import cli
from fxc_env.baselines.harness.jobs import Job, run_job
from fxc_env.baselines.harness.suite import builtin_contenders, learned_contender
from fxc_env.config.tasks import TASKS
from fxc_env.policies.learned import load_learned_policy, pretrained_path
from fxc_env.policies.torch_policy import TorchPolicy
from fxc_env.training.evaluation.evaluate import task_suite

ROOT = Path(__file__).resolve().parents[2]
TASK = TASKS["rings20-v2"]
#: Per shipped policy: its back end, and how far below the reference's median it must be on the 20 seeds.
GOALS = {"ppo_rings20": ("torch", 1.0), "diff_rings20": ("diff", 10.0)}


def recipe(backend: str) -> list[str]:
    """The README's command for the policy of ``backend`` on rings20-v2, as the arguments after ``fxc``."""
    text = (ROOT / "fxc_env" / "pretrained" / "README.md").read_text()
    commands = re.findall(rf"`\.venv/bin/fxc (train --backend {backend} --task rings20-v2 [^`]*)`", text)
    assert len(commands) == 1, commands
    return shlex.split(commands[0])


def with_value(argv: list[str], flag: str, value: str) -> list[str]:
    """``argv`` with ``flag``'s value replaced by ``value``."""
    at = argv.index(flag) + 1
    return [*argv[:at], value, *argv[at + 1 :]]


def task_medians(name: str, seeds: tuple[int, ...]) -> tuple[float, float]:
    """Median D(T_s)/D(0) of the shipped ``name`` and of the reference on rings20-v2's episodes of ``seeds``."""
    suite, learned = task_suite(TASK)
    medians = []
    for contender in (learned_contender(name, **learned), builtin_contenders(["reference"])[0]):
        job = Job(contender, suite.cases[0], TASK.n_intervals, seeds, suite.settling_time, False)
        result = run_job(job)
        assert result.error is None, result.error
        medians.append(float(np.median(result.metrics["relative_deadline_error"])))
    return medians[0], medians[1]


@pytest.mark.parametrize("name", list(GOALS))
def test_a_rings20_policy_loads_by_name_and_meets_its_goal_on_five_evaluation_seeds(name):
    assert isinstance(load_learned_policy(name, fxc_env.parallel_env(**TASK.kwargs())), TorchPolicy)
    ours, reference = task_medians(name, TASK.eval_seeds[:5])
    assert 0.05 < reference < 0.5  # the reference's residual at K = 50 (about 0.2 over all 20 seeds)
    assert ours * GOALS[name][1] < reference


@pytest.mark.slow
@pytest.mark.parametrize("name", list(GOALS))
def test_fxc_evaluate_scores_a_rings20_policy_at_its_goal_on_the_tasks_20_seeds(name, tmp_path):
    argv = ["evaluate", "--task", "rings20-v2", "--policy", name, "--out", str(tmp_path)]
    assert cli.main([*argv, "--no-progress", "--workers", "1"]) == 0
    rows = {row["policy"]: row for row in csv.DictReader((tmp_path / "results.csv").open())}
    assert {int(row["n_episodes"]) for row in rows.values()} == {20}
    ours = float(rows[f"learned:{name}"]["relative_deadline_error_median"])
    reference = float(rows["reference"]["relative_deadline_error_median"])
    assert reference < 0.25  # 0.199
    assert ours * GOALS[name][1] < reference


@pytest.mark.parametrize("name", list(GOALS))
def test_the_readme_command_trains_the_shipped_network_from_scratch_on_the_task(name, tmp_path):
    """One batch of the README's command: the task's environment, the file's settings, no teacher, the same network."""
    backend = GOALS[name][0]
    argv = recipe(backend)
    assert "--init-from" not in argv and "--policy-arch" not in argv  # no teacher; the MLP
    shipped = torch.load(pretrained_path(name), weights_only=True)
    assert shipped["timesteps"] == int(argv[argv.index("--timesteps") + 1])  # the file is the command's whole run
    argv = with_value(argv, "--hyperparams", str(ROOT / argv[argv.index("--hyperparams") + 1]))
    argv = with_value(with_value(argv, "--timesteps", "64000"), "--run-dir", str(tmp_path / "run"))  # one batch
    assert cli.main([*argv, "--no-progress-bar"]) == 0
    record = json.loads((tmp_path / "run" / "config.json").read_text())
    assert record["args"]["task"] == "rings20-v2" and record["args"]["init_from"] is None
    assert record["hyperparams"]["env"]["action_mode"] == "plan_balanced"  # not residual: the task's own actions
    section = "torch_ppo" if backend == "torch" else "diff_apg"
    entry = yaml.safe_load((ROOT / "training" / "recipes" / "rings20_v2.yml").read_text())["rings20-v2"][section]
    assert {key: record[section][key] for key in entry} == entry  # every setting of the file's entry, as written
    trained = torch.load(tmp_path / "run" / "policy.pt", weights_only=True)
    for key in ("format", "arch", "hidden", "activation", "obs_size", "action_size", "action_bound", "env", "domain"):
        assert trained[key] == shipped[key], key
    assert {k: v.shape for k, v in trained["actor"].items()} == {k: v.shape for k, v in shipped["actor"].items()}
    assert trained["timesteps"] == 64000
