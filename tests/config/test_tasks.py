"""Named, versioned tasks: frozen settings, evaluation seeds and K, under the same id in every front end."""

from __future__ import annotations

import pettingzoo
import pytest

import fxc_env
from fxc_env.cli.main import main
from fxc_env.config import make_config
from fxc_env.config.tasks import EVALUATION_SEEDS_V1, TASKS, get_task, task_kwargs
from fxc_env.core.validation import ArgumentError

#: The v1 tasks as released. A change here is a change of settings: add a -v2 task, never edit a -v1 one.
V1 = {
    "paper_fig1-v1": {"scenario": "paper_fig1", "n_intervals": 200},
    "rings20-v1": {"n_agents": 20, "topology": "ring", "settling_time": 20.0, "n_intervals": 200},
    "generalist-v1": {"scenario": "generalist", "n_intervals": 200},
    "saturated-v1": {"scenario": "saturated", "n_intervals": 200},
}

#: The v2 tasks as released: v1's settings at K = 50 with the plan_balanced interface in a ±1 box; generalist-v2's
#: reward floored at 1e-3 D(0) (its return stops paying for over-solving the easy episodes).
V2_INTERFACE = {"action_mode": "plan_balanced", "action_bound": 1.0, "n_intervals": 50}
V2_OWN = {"generalist-v2": {"reward_floor": 1e-3}}
V2 = {
    name.replace("-v1", "-v2"): {**settings, **V2_INTERFACE, **V2_OWN.get(name.replace("-v1", "-v2"), {})}
    for name, settings in V1.items()
}

#: What each v1 task resolves to (N, K, T_s, schedule, input limits, observation slots): the scenarios'
#: presets it names must not drift under it either.
RESOLVED = {
    "paper_fig1-v1": (6, 200, 20.0, "paper", None, None),
    "rings20-v1": (20, 200, 20.0, "paper", None, None),
    "generalist-v1": (20, 200, 20.0, "paper", None, 4),
    "saturated-v1": (6, 200, 20.0, "uniform", (10.0, 100.0, 1000.0), 4),
}


def test_the_v1_tasks_keep_their_settings_seeds_and_k():
    assert {name: dict(task.settings) for name, task in TASKS.items() if task.version == 1} == V1
    for name, task in TASKS.items():
        assert task.eval_seeds == EVALUATION_SEEDS_V1 == tuple(range(1000, 1020))
        assert task.full_id == f"fxc/{name}" and task.n_intervals == (200 if task.version == 1 else 50)


def test_the_v2_tasks_are_the_v1_tasks_on_the_balanced_interface_at_k_50():
    assert {name: dict(task.settings) for name, task in TASKS.items() if task.version == 2} == V2
    assert set(TASKS) == set(V1) | set(V2)
    for name in V2:
        config = make_config(**task_kwargs(name))
        assert (config.action_mode, config.action_bound, config.n_intervals) == ("plan_balanced", 1.0, 50)
        assert config.reward_floor == (1e-3 if name == "generalist-v2" else 1e-12)


@pytest.mark.parametrize("name", sorted(RESOLVED))
def test_each_task_resolves_to_its_frozen_environment(name):
    config = make_config(**task_kwargs(name))
    slots = None if RESOLVED[name][5] is None else config.obs_slots
    resolved = (config.n_agents, config.n_intervals, config.settling_time, config.schedule.name)
    assert (*resolved, config.u_max_choices, slots) == RESOLVED[name]


@pytest.mark.parametrize("api", ["parallel", "aec"])
def test_pettingzoo_makes_every_task_by_its_id(api):
    for task in TASKS.values():
        env = pettingzoo.make(api, task.full_id)
        config = env.unwrapped.config
        n_agents, n_intervals = RESOLVED[task.id.replace("-v2", "-v1")][:2]
        assert (config.n_agents, config.n_intervals) == (n_agents, n_intervals if task.version == 1 else 50)
        assert config.action_mode == ("plan" if task.version == 1 else "plan_balanced")
    env = pettingzoo.make("parallel", "fxc/rings20-v1", n_intervals=50)  # a keyword overrides, as for any id
    assert env.unwrapped.config.n_intervals == 50


@pytest.mark.parametrize("api", ["parallel", "aec"])
def test_pettingzoo_refuses_a_task_id_without_its_version_as_get_task_does(api):
    # Issue 33: PettingZoo resolves an unversioned id to the newest version, so "fxc/rings20" ran v1 silently.
    for task in TASKS.values():
        unversioned = f"fxc/{task.name}"
        with pytest.raises(ArgumentError) as refusal:
            pettingzoo.make(api, unversioned)
        with pytest.raises(ArgumentError) as expected:
            get_task(unversioned, argument="id")
        message = str(refusal.value)
        assert message == str(expected.value)
        assert message.startswith("id: a task name carries its version") and repr(task.full_id) in message


def test_the_same_settings_reach_the_parallel_env_by_keyword():
    env = fxc_env.parallel_env(**task_kwargs("fxc/rings20-v1"))
    assert env.possible_agents == [f"agent_{i}" for i in range(20)]


def test_task_kwargs_is_a_fresh_copy():
    task_kwargs("rings20-v1")["n_agents"] = 3
    assert TASKS["rings20-v1"].settings["n_agents"] == 20


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("rings20", "task: a task name carries its version"),
        ("rings20-v9", "task: expected one of"),
        (None, "task: expected one of"),
    ],
)
def test_an_unknown_or_unversioned_task_is_refused_by_name(name, message):
    with pytest.raises(ArgumentError, match=message):
        get_task(name)


def test_fxc_evaluate_scores_a_task_on_its_evaluation_seeds_at_its_k(tmp_path, capsys):
    assert main(["evaluate", "--task", "fxc/rings20-v1", "--policy", "reference", "--out", str(tmp_path),
                 "--workers", "1", "--no-progress"]) == 0  # fmt: skip
    table = (tmp_path / "table.md").read_text()
    assert "rings20-v1 suite: 1 cases (ring; N in [20]), 20 seeded initial states" in table
    assert "seeds 1000..1019" in table
    assert "| reference | 200 |" in table


@pytest.mark.parametrize("flag", [["--seeds", "5"], ["--budgets", "50"], ["--suite", "realism"], ["--n-agents", "8"]])
def test_fxc_evaluate_refuses_a_flag_the_task_fixes(flag, tmp_path, capsys):
    argv = ["evaluate", "--task", "rings20-v1", "--policy", "reference", "--out", str(tmp_path), *flag]
    assert main(argv) == 2
    assert f"{flag[0]}: --task rings20-v1 fixes" in capsys.readouterr().err
    assert not (tmp_path / "table.md").exists()


def test_torchrl_builds_a_task_from_the_same_settings():
    from fxc_env.envs.torch_env import ConsensusTorchEnv

    env = ConsensusTorchEnv(batch_size=3, seed=0, **task_kwargs("rings20-v1"))
    td = env.reset()
    assert td["agents", "observation"].shape[:2] == (3, 20) and env.config.n_intervals == 200
