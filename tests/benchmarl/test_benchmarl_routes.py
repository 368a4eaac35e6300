"""BenchMARL's own routes run the named, versioned tasks unmodified: its command line (Hydra) and ``Benchmark``."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
from benchmarl.algorithms import MappoConfig
from benchmarl.benchmark import Benchmark
from benchmarl.environments import task_config_registry
from benchmarl.experiment import ExperimentConfig
from benchmarl.hydra_config import load_task_config_from_hydra
from benchmarl.models import MlpConfig
from hydra import compose, initialize_config_module
from hydra.core.global_hydra import GlobalHydra

from fxc_env.config.tasks import TASKS
from fxc_env.envs.benchmarl_task import BENCHMARL_SETTINGS, FxcTask, FxcTaskClass, register

VERSIONED = [member for member in FxcTask if member.task_name in TASKS]
FRAMES = 400  # one batch: two environments x one episode of the tasks' K = 200 steps

#: BenchMARL's command line shrunk to one batch of FRAMES frames on the CPU, CSV logs only, no evaluation.
TINY = [
    "experiment.sampling_device=cpu",
    "experiment.train_device=cpu",
    "experiment.buffer_device=cpu",
    f"experiment.max_n_frames={FRAMES}",
    f"experiment.on_policy_collected_frames_per_batch={FRAMES}",
    "experiment.on_policy_n_envs_per_worker=2",
    "experiment.on_policy_n_minibatch_iters=1",
    f"experiment.on_policy_minibatch_size={FRAMES}",
    "experiment.evaluation=false",
    "experiment.loggers=[csv]",
    "experiment.create_json=false",
    "experiment.render=false",
    "experiment.checkpoint_at_end=false",
]


def frames_logged(folder: Path) -> dict[str, float]:
    """The last total-frames counter of every experiment under ``folder``, by experiment folder name."""
    counters = {}
    for path in folder.glob("**/scalars/counters_total_frames.csv"):
        with open(path) as file:
            counters[path.parents[1].name] = float(list(csv.reader(file))[-1][-1])
    return counters


def test_every_task_is_in_benchmarls_registry_and_hydras_task_group():
    register()  # what python -m fxc_env.envs.benchmarl_run does before BenchMARL's hydra_experiment
    GlobalHydra.instance().clear()
    with initialize_config_module(config_module="benchmarl.conf", version_base=None):
        for member in VERSIONED:
            cfg = compose(config_name="config", overrides=["algorithm=mappo", f"task=fxc/{member.task_name}"])
            task = load_task_config_from_hydra(cfg.task, f"fxc/{member.task_name}")  # BenchMARL's own loader
            assert isinstance(task, FxcTaskClass)
            assert task.config == {**TASKS[member.task_name].settings, **BENCHMARL_SETTINGS}
        cfg = compose(config_name="config", overrides=["algorithm=mappo", "task=fxc/paper_fig1"])  # the scenarios too
        assert cfg.task.scenario == "paper_fig1"
    GlobalHydra.instance().clear()
    assert task_config_registry["fxc/rings20-v1"] is FxcTask.RINGS20_V1


def test_a_versioned_tasks_config_is_its_frozen_settings_with_benchmarls_float32():
    task = FxcTask.RINGS20_V1.get_from_yaml()
    assert task.config == {**TASKS["rings20-v1"].kwargs(), "obs_dtype": "float32", "global_state": "normalized"}
    env = task.get_env_fun(num_envs=2, continuous_actions=True, seed=0, device="cpu")()
    assert env.config.n_agents == 20 and task.max_steps(env) == 200


@pytest.mark.slow
def test_benchmarls_command_line_runs_every_task(tmp_path):
    """``python -m fxc_env.envs.benchmarl_run algorithm=mappo task=fxc/<task>-v1``: BenchMARL's own Hydra entry, once per task."""
    tasks = ",".join(f"fxc/{member.task_name}" for member in VERSIONED)
    command = [
        sys.executable,
        "-m",
        "fxc_env.envs.benchmarl_run",
        "--multirun",
        "algorithm=mappo",
        f"task={tasks}",
        *TINY,
    ]
    command += [f"experiment.save_folder={tmp_path}", f"hydra.sweep.dir={tmp_path / 'hydra'}"]
    result = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    counters = frames_logged(tmp_path)
    assert sorted(name.split("_mlp_")[0] for name in counters) == sorted(
        f"mappo_{member.name.lower()}" for member in VERSIONED
    )
    assert set(counters.values()) == {FRAMES}


@pytest.mark.slow
def test_benchmarls_benchmark_runs_every_task(tmp_path):
    config = ExperimentConfig.get_from_yaml()  # TINY, in Python
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = config.on_policy_collected_frames_per_batch = config.on_policy_minibatch_size = FRAMES
    config.on_policy_n_envs_per_worker = 2
    config.on_policy_n_minibatch_iters = 1
    config.evaluation = config.create_json = config.render = config.checkpoint_at_end = False
    config.loggers = ["csv"]
    config.save_folder = str(tmp_path)
    benchmark = Benchmark(
        algorithm_configs=[MappoConfig.get_from_yaml()],
        tasks=[member.get_from_yaml() for member in VERSIONED],
        seeds={0},
        experiment_config=config,
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
    )
    benchmark.run_sequential()
    counters = frames_logged(tmp_path)
    assert len(counters) == len(VERSIONED) == 4
    assert set(counters.values()) == {FRAMES}


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["MasacConfig", "MaddpgConfig"])
def test_off_policy_algorithms_with_q_critics_train_on_a_task(algorithm, tmp_path):
    """MASAC's and MADDPG's critics read the float32 action beside the observation (the task casts it)."""
    from benchmarl import algorithms
    from benchmarl.experiment import Experiment

    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = config.off_policy_collected_frames_per_batch = FRAMES
    config.off_policy_n_envs_per_worker = 2
    config.off_policy_n_optimizer_steps = 2
    config.off_policy_train_batch_size = 64
    config.off_policy_init_random_frames = 0
    config.evaluation = config.create_json = config.render = config.checkpoint_at_end = False
    config.loggers = []
    config.save_folder = str(tmp_path)
    experiment = Experiment(
        task=FxcTask.RINGS20_V1.get_from_yaml(),
        algorithm_config=getattr(algorithms, algorithm).get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=0,
        config=config,
    )
    experiment.run()
    assert experiment.total_frames == FRAMES
