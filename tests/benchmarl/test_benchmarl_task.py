"""The BenchMARL task: a MAPPO experiment with BenchMARL's GNN actor runs on it, and its specs are the env's."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch_geometric
from benchmarl.algorithms import IppoConfig, MappoConfig
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models import GnnConfig, MlpConfig
from benchmarl.models.gnn import Gnn
from torchrl.envs import Compose, TransformedEnv

from fxc_env.config.scenarios import SCENARIOS
from fxc_env.config.tasks import TASKS
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.benchmarl_task import FxcTask, FxcTaskClass
from fxc_env.envs.torch_env import GROUP, ConsensusTorchEnv

K = 10  # sampling intervals per episode: a tiny task
FRAMES = 120  # the experiment's budget: 3 iterations of 2 episodes x 10 steps x 2 (per batch: 40 frames)


def tiny_config(folder: Path) -> ExperimentConfig:
    """BenchMARL's default experiment shrunk to a few hundred frames on the CPU, CSV logs in ``folder`` only."""
    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = FRAMES
    config.on_policy_collected_frames_per_batch = 40
    config.on_policy_n_envs_per_worker = 2
    config.on_policy_n_minibatch_iters = 1
    config.on_policy_minibatch_size = 20
    config.evaluation = True
    config.evaluation_interval = FRAMES
    config.evaluation_episodes = 2
    config.loggers = ["csv"]  # nothing to the network
    config.create_json = False
    config.render = False
    config.checkpoint_at_end = False
    config.save_folder = str(folder)
    return config


def paper_task(**overrides) -> FxcTaskClass:
    task = FxcTask.PAPER_FIG1.get_from_yaml()
    task.config.update(n_intervals=K, **overrides)
    return task


def gnn_actor() -> GnnConfig:
    return GnnConfig(topology="full", self_loops=False, gnn_class=torch_geometric.nn.conv.GATv2Conv, gnn_kwargs={})


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    """MAPPO, BenchMARL's GNN as the actor, an MLP critic on the global state, on paper_fig1 with K = 10."""
    folder = tmp_path_factory.mktemp("benchmarl")
    experiment = Experiment(
        task=paper_task(),
        algorithm_config=MappoConfig.get_from_yaml(),
        model_config=gnn_actor(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=0,
        config=tiny_config(folder),
    )
    experiment.run()
    return experiment


@pytest.mark.slow
def test_the_experiment_runs_to_its_frame_budget_and_logs_under_its_folder(experiment):
    assert experiment.total_frames == FRAMES
    assert experiment.n_iters_performed == FRAMES // 40
    [counter] = Path(experiment.config.save_folder).glob("**/scalars/counters_total_frames.csv")
    with open(counter) as file:
        rows = list(csv.reader(file))
    assert float(rows[-1][-1]) == FRAMES


@pytest.mark.slow
def test_the_actor_is_benchmarls_gnn_over_the_six_agents(experiment):
    gnns = [module for module in experiment.policy.modules() if isinstance(module, Gnn)]
    assert gnns and all(gnn.n_agents == 6 for gnn in gnns)


@pytest.mark.slow
def test_the_trained_policy_acts_within_the_envs_action_spec(experiment):
    base = experiment.task.get_env_fun(num_envs=3, continuous_actions=True, seed=1, device="cpu")()
    env = TransformedEnv(base, Compose(*experiment.task.get_env_transforms(base)))  # as BenchMARL wraps it
    with torch.no_grad():
        rollout = env.rollout(K, experiment.policy)
    spec = env.action_spec[GROUP, "action"]
    actions = rollout[GROUP, "action"]
    assert rollout.batch_size == torch.Size([3, K])  # whole episodes: terminated at the deadline, step K
    assert actions.shape == (3, K, 6, base.config.action_size)
    # BenchMARL's float32 networks act in float32; the engine receives them cast to its float64.
    assert actions.dtype == spec.dtype == torch.float32 and base.action_spec[GROUP, "action"].dtype == torch.float64
    assert rollout["next", GROUP, "reward"].dtype == torch.float32
    assert all(spec.is_in(actions[:, k]) for k in range(K))
    assert float(actions.abs().max()) > 0  # the network acts: not an all-zero (coasting) policy
    assert bool(rollout["next", "terminated"][:, -1].all())


def test_the_tasks_specs_group_map_and_max_steps_are_the_envs():
    task = paper_task(max_cycles=7)
    env = task.get_env_fun(num_envs=4, continuous_actions=True, seed=0, device="cpu")()
    assert isinstance(env, ConsensusTorchEnv) and env.batch_size == torch.Size([4])
    observation = task.observation_spec(env)[GROUP, "observation"]
    assert observation == env.observation_spec[GROUP, "observation"][0]
    assert observation.shape == (6, env.config.layout.size) and observation.dtype == torch.float32
    assert list(task.observation_spec(env).keys()) == [GROUP]  # the state is the task's state_spec, not an input
    assert task.state_spec(env)["state"].shape == (6 * 2 + 3,)
    assert task.action_spec(env)[GROUP, "action"] == env.action_spec[GROUP, "action"][0]
    assert task.group_map(env) == {GROUP: [f"agent_{i}" for i in range(6)]}
    assert task.max_steps(env) == 7  # max_cycles cuts the K = 10 intervals
    assert task.supports_continuous_actions() and not task.supports_discrete_actions()


def test_without_a_global_state_the_task_has_no_state_spec():
    task = paper_task(global_state="raw")
    env = task.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")()
    assert task.state_spec(env) is None
    assert task.max_steps(env) == K


def test_graph_tensors_reach_the_data_as_root_entries_beside_the_models_inputs():
    task = paper_task(graph_tensors=True)
    env = task.get_env_fun(num_envs=2, continuous_actions=True, seed=0, device="cpu")()
    td = env.reset()
    # The assumed Fig. 1's first graph: 1 -> 2 and 4 -> 5 (0-based sources in row 0, targets in row 1).
    assert td["n_edges"].tolist() == [2, 2]
    assert td["edge_index"][0][:, td["edge_mask"][0]].T.tolist() == [[0, 1], [3, 4]]
    assert list(task.observation_spec(env).keys()) == [GROUP]  # models read the group's observation only


def test_every_named_scenario_is_a_task_whose_shipped_config_builds_its_env():
    assert {member.task_name for member in FxcTask} == set(SCENARIOS) | set(TASKS)
    for member in FxcTask:
        if member.task_name not in SCENARIOS:
            continue
        task = member.get_from_yaml()
        assert task.config["scenario"] == member.task_name
        env = task.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")()
        assert env.config.n_agents == SCENARIOS[member.task_name]["n_agents"]


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({"scenario": "paper_fig1", "batch_size": 8}, "batch_size: set by BenchMARL"),
        ({"scenario": "paper_fig1", "seed": 3}, "seed: set by BenchMARL"),
        ({"scenario": "paper_fig1", "n_agent": 6}, "n_agent: not a ConsensusTorchEnv argument"),
        ({"scenario": "paper_fig1", "n_intervals": 0}, "n_intervals"),
        ({"scenario": "no_such_scenario"}, "scenario"),
    ],
)
def test_a_bad_task_config_is_refused_by_name(config, message):
    with pytest.raises(ArgumentError, match=message):
        FxcTask.PAPER_FIG1.get_task(config=config)


def test_an_algorithm_with_discrete_actions_only_is_refused_by_name():
    with pytest.raises(ArgumentError, match="continuous_actions"):
        paper_task().get_env_fun(num_envs=1, continuous_actions=False, seed=0, device="cpu")


def test_a_yaml_config_that_is_not_a_mapping_is_refused(tmp_path):
    path = tmp_path / "task.yaml"
    path.write_text("- scenario\n- paper_fig1\n")
    with pytest.raises(ArgumentError, match="path: expected a YAML mapping"):
        FxcTask.PAPER_FIG1.get_from_yaml(str(path))


@pytest.mark.slow
def test_ippo_runs_with_an_mlp_actor_and_no_global_state(tmp_path):
    experiment = Experiment(
        task=paper_task(global_state="raw"),
        algorithm_config=IppoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=0,
        config=tiny_config(tmp_path),
    )
    experiment.run()
    assert experiment.total_frames == FRAMES


def test_importing_fxc_env_does_not_import_benchmarl():
    code = "import sys, fxc_env; print('benchmarl' in sys.modules, 'torch_geometric' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["False", "False"]


def test_without_benchmarl_the_import_names_the_extra_to_install():
    code = "import sys; sys.modules['benchmarl'] = None; import fxc_env.envs.benchmarl_task"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 1
    assert 'ModuleNotFoundError: fxc_env.envs.benchmarl_task needs BenchMARL: pip install "fxc-env[benchmarl]"' in (
        result.stderr
    )
