"""``fxc leaderboard`` end to end at a tiny budget: one task, MAPPO, one seed, beside the laws; it resumes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fxc_env.cli.main import build_parser, main
from fxc_env.config.tasks import TASKS
from fxc_env.training.evaluation.leaderboard import (
    ALGORITHMS,
    SHIPPED_TASKS,
    build_experiment,
    headline_lines,
    policy_actor,
    score_actor,
)
from fxc_env.training.evaluation.leaderboard_runs import CURVE_POINTS, SETTINGS

FRAMES = 400  # two environments x one episode of K = 200 steps: one BenchMARL batch
ARGV = ["leaderboard", "--frames", str(FRAMES), "--seeds", "1", "--tasks", "rings20-v1", "--algorithms", "mappo"]


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    out = tmp_path_factory.mktemp("leaderboard")
    assert main([*ARGV, "--out", str(out), "--bootstrap-reps", "200"]) == 0
    return out


@pytest.mark.slow
def test_the_table_ranks_mappo_beside_the_laws_and_the_shipped_policies(board):
    table = (board / "table.md").read_text()
    rows = {line.split(" | ")[0].lstrip("| ") for line in table.splitlines() if line.startswith("| ")}
    assert {"mappo", "reference", "minimum_time", "leader_follower", "graph_agnostic", "signalling"} <= rows
    assert {"learned:generalist", "learned:rings", "learned:rings_gru"} <= rows
    assert (board / "performance_profile.png").stat().st_size > 0
    versions = json.loads((board / "versions.json").read_text())  # what a shipped table must say it ran on
    assert {"python", "torch", "torchrl", "benchmarl", "fxc_env", "fxc_env_commit"} <= set(versions)
    assert "- rings20-v1: best algorithm mappo " in table and "the paper's law (reference)" in table


@pytest.mark.slow
def test_every_contender_is_scored_on_the_tasks_evaluation_seeds(board):
    run = json.loads((board / "rings20-v1" / "mappo" / "seed0.json").read_text())
    assert run["frames"] == FRAMES and run["task"] == "fxc/rings20-v1"
    n_seeds = len(TASKS["rings20-v1"].eval_seeds)
    marl_eval = json.loads((board / "marl_eval.json").read_text())["fxc_env"]["rings20-v1"]
    assert len(marl_eval["mappo"]["seed_0"]["absolute_metrics"]["deadline_error"]) == n_seeds
    assert len(marl_eval["reference"]["seed_0"]["absolute_metrics"]["deadline_error"]) == n_seeds
    laws = json.loads((board / "rings20-v1" / "laws.json").read_text())
    assert laws["seeds"] == list(range(1000, 1020))


@pytest.mark.slow
def test_each_run_records_its_curve_from_the_untrained_actor_to_the_trained_one_and_its_cost(board, tmp_path):
    run = json.loads((board / "rings20-v1" / "mappo" / "seed0.json").read_text())
    frames = [point["frames"] for point in run["curve"]]
    assert frames[0] == 0 and frames[-1] == run["frames"] and len(frames) <= CURVE_POINTS + 1
    assert run["curve"][-1]["deadline_error"] == run["deadline_error"]  # the table's score: the curve's end
    experiment, _ = build_experiment(TASKS["rings20-v1"], "mappo", 0, FRAMES, tmp_path)  # the same seed, untrained
    assert (
        run["curve"][0]["deadline_error"]
        == score_actor(TASKS["rings20-v1"], policy_actor(experiment.policy))["deadline_error"]
    )
    assert run["frames_per_second"] > 0 and run["seconds"]["update"] > 0
    table = (board / "table.md").read_text()
    assert "| mappo@0 | " in table and "| zero | " in table and "| random | " in table
    assert "| rings20-v1 | mappo | 400 |" in table  # the cost table
    assert (board / "curves_rings20-v1.png").stat().st_size > 0


@pytest.mark.slow
def test_a_rerun_resumes_without_training_again(board, capsys):
    run = board / "rings20-v1" / "mappo" / "seed0.json"
    before = run.stat().st_mtime_ns
    capsys.readouterr()
    assert main([*ARGV, "--out", str(board), "--bootstrap-reps", "200"]) == 0
    assert "mappo, seed 0" not in capsys.readouterr().out  # no training line: the run was kept
    assert run.stat().st_mtime_ns == before


@pytest.mark.slow
def test_a_rerun_with_another_budget_is_refused(board, capsys):
    argv = [*ARGV, "--out", str(board)]
    argv[2] = str(2 * FRAMES)
    assert main(argv) == 2
    assert f"--frames: {board / 'rings20-v1' / 'mappo' / 'seed0.json'} was trained for {FRAMES} frames" in (
        capsys.readouterr().err
    )


def test_mappo_grus_actor_is_scored_with_its_hidden_state_carried_from_step_to_step(tmp_path):
    """BenchMARL's GRU actor sees the history: the same observation at the second step acts otherwise, and a
    fresh scoring loop starts again from the zero hidden state (``is_init``), as BenchMARL's collector does."""
    experiment, actor = build_experiment(TASKS["rings20-v1"], "mappo_gru", 0, FRAMES, tmp_path)
    hidden = (actor.n_layers, actor.hidden_size)
    size = experiment.observation_spec["agents", "observation"].shape[-1]
    obs = np.random.default_rng(0).normal(size=(3, 20, size))
    act = policy_actor(experiment.policy, hidden)
    first, second = act(obs), act(obs)
    assert first.shape == (3, 20, 2)
    assert not np.allclose(first, second)
    np.testing.assert_array_equal(policy_actor(experiment.policy, hidden)(obs), first)


def test_an_mlp_actor_is_scored_without_state(tmp_path):
    experiment, _ = build_experiment(TASKS["rings20-v1"], "mappo", 0, FRAMES, tmp_path)
    obs = np.random.default_rng(0).normal(size=(3, 20, experiment.observation_spec["agents", "observation"].shape[-1]))
    act = policy_actor(experiment.policy)
    np.testing.assert_array_equal(act(obs), act(obs))


def test_the_headline_says_by_how_many_decades_the_best_algorithm_loses_to_the_papers_law():
    tasks = [TASKS["rings20-v1"], TASKS["saturated-v1"]]
    scores = {
        "mappo": {"rings20-v1": np.array([[1e-3, 1e-3]]), "saturated-v1": np.array([[1e-14]])},
        "ippo": {"rings20-v1": np.array([[1e-2, np.inf]]), "saturated-v1": np.array([[1.0]])},
        "reference": {"rings20-v1": np.array([[1e-9, 1e-9]]), "saturated-v1": np.array([[1e-6]])},
    }
    lines = headline_lines(tasks, ["mappo", "ippo"], scores)
    assert lines[1] == (
        "- rings20-v1: best algorithm mappo 0.001 vs the paper's law (reference) 1e-09: learning loses by 6.0 decades "
        "(best of all: reference 1e-09)"
    )
    assert "learning matches or beats it by 6.0 decades (best of all: mappo 1e-14)" in lines[2]  # floored at 1e-12
    assert headline_lines(tasks, [], scores) == []  # --algorithms none: no headline


SHIPPED = Path(__file__).resolve().parents[2] / "fxc_env" / "assets" / "leaderboard"


def test_the_shipped_table_is_what_fxc_leaderboards_defaults_reproduce():
    """``fxc leaderboard`` with its defaults is the shipped table's command: every task, algorithm and seed."""
    table = (SHIPPED / "table.md").read_text()
    assert "Command: `fxc leaderboard --frames 1000 --seeds 3 --out out/leaderboard`" in table
    defaults = build_parser().parse_args(["leaderboard"])
    assert (defaults.frames, defaults.seeds, defaults.tasks, defaults.algorithms) == (
        ["1000"],
        3,
        list(SHIPPED_TASKS),
        list(ALGORITHMS),
    )
    assert SHIPPED_TASKS == tuple(task for task in TASKS if task.endswith("-v1"))
    runs = json.loads((SHIPPED / "marl_eval.json").read_text())["fxc_env"]
    assert set(runs) == set(SHIPPED_TASKS)
    for task in SHIPPED_TASKS:
        for algorithm in ALGORITHMS:
            seeds = runs[task][algorithm]
            assert sorted(seeds) == ["seed_0", "seed_1", "seed_2"]
            assert len(seeds["seed_0"]["absolute_metrics"]["deadline_error"]) == len(TASKS[task].eval_seeds)
    assert set(json.loads((SHIPPED / "versions.json").read_text())) >= {"python", "torch", "torchrl", "benchmarl"}


def test_the_v2_settings_reach_benchmarl_per_kind_of_algorithm(tmp_path):
    """On a v2 task the on-policy algorithms train with Adam at 1e-3 and an exploration scale floored at 0.1
    (``scale_mapping``), the off-policy ones at 3e-4 with BenchMARL's default mapping (results.md, "BenchMARL on
    the v2 tasks"); every algorithm of a kind the same."""
    task = TASKS["rings20-v2"]
    seen = {}
    for algorithm in ("mappo", "ippo", "masac", "maddpg"):
        experiment, _ = build_experiment(task, algorithm, 0, 6400, tmp_path / algorithm)
        seen[algorithm] = (experiment.config.lr, getattr(experiment.algorithm_config, "scale_mapping", None))
    on_policy = SETTINGS[2]["on_policy"]
    assert seen["mappo"] == seen["ippo"] == (on_policy["lr"], on_policy["algorithm"]["scale_mapping"])
    assert seen["mappo"] == (1e-3, "biased_softplus_0.22_0.1")
    assert seen["masac"] == (3e-4, "biased_softplus_1.0") and seen["maddpg"][0] == 3e-4
    for name in ("saturated-v2", "generalist-v2"):  # the tasks' own: MAPPO collapsed, IPPO drifted (results.md)
        for algorithm in ("mappo", "ippo"):
            experiment, _ = build_experiment(TASKS[name], algorithm, 0, 6400, tmp_path / name / algorithm)
            config = experiment.algorithm_config
            # generalist-v2's own rate and GAE lambda (IPPO's one-agent critic only a baseline), the kind's scale floor
            assert experiment.config.lr == (1e-4 if name == "generalist-v2" else 3e-4), (name, algorithm)
            assert (config.lmbda, config.scale_mapping) == (
                1.0 if name == "generalist-v2" else 0.9,
                "biased_softplus_0.22_0.1",
            ), (name, algorithm)
