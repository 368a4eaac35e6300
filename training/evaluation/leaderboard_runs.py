"""``fxc leaderboard``'s BenchMARL runs: the settings per task version, the experiment, its learning curve and cost.

A run trains one algorithm on one task for a frame budget and records, besides the trained actor's scores,
its **learning curve**: the deterministic actor scored on the task's frozen evaluation seeds before training
(0 frames: the ``<algorithm>@0`` row of the table) and after the first batch at or past each of
:data:`CURVE_POINTS` evenly spaced frame counts (the last: the end of training, the table's score), and its
**cost**: seconds collecting, seconds updating, seconds scoring the curve (not counted as training) and
frames per second of training (frames / (collecting + updating)). The actors beside them that need no
training: the zero action (``zero``) and uniform random actions over the box (``random``, seeded). Docs:
results.md, "MARL algorithms table".
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.config import make_config
from fxc_env.config.tasks import NamedTask
from fxc_env.policies.protocol import seeded_metrics
from fxc_env.training.evaluation.evaluate import scored_settings
from fxc_env.training.evaluation.leaderboard_files import result_record

#: BenchMARL's algorithms in the table: (algorithm config, actor model). MADDPG is the deterministic one.
ALGORITHMS = {
    "mappo": ("MappoConfig", "mlp"),
    "ippo": ("IppoConfig", "mlp"),
    "masac": ("MasacConfig", "mlp"),
    "maddpg": ("MaddpgConfig", "mlp"),
    "mappo_gnn": ("MappoConfig", "gnn"),
    "mappo_gru": ("MappoConfig", "gru"),
}
#: Evaluations of the deterministic actor during a run besides the one at 0 frames (evenly spaced in frames): 16,
#: so that a run of 1,024k frames is scored at 64k (where the goal "below the zero action within 100k" is read).
CURVE_POINTS = 16
#: The seed of the uniform random actions of the ``random`` row.
RANDOM_SEED = 0
#: BenchMARL's algorithms that learn from a replay buffer (the rest learn on-policy).
OFF_POLICY = frozenset({"masac", "maddpg"})
#: BenchMARL's experiment settings per task version, the same for every algorithm of a kind. Version 1 (the
#: shipped v1 table): BenchMARL's defaults with batches shrunk to the budget. Version 2 (lean, so that the whole
#: v2 table trains on two CPU cores within two hours): one batch is 64 whole episodes (64 K frames: 3,200 at
#: K = 50); on-policy algorithms take 4 passes over it in minibatches of 400 frames, off-policy ones 50 gradient
#: steps of 256 frames from the replay buffer (BenchMARL's default is 1,000 per 6,000 frames: 533 per batch); no
#: discount (the rewards telescope to ln D(0)/D(T_s) over the episode: docs environment.md); actor and critic
#: MLPs of two tanh layers of 64 (BenchMARL's default: 256). Per kind (``on_policy``/``off_policy``): Adam's
#: ``lr`` and the algorithm config's fields. On-policy: lr 1e-3 and ``scale_mapping`` "biased_softplus_0.22_0.1",
#: the Gaussian's scale softplus(x + b) + 0.1 with b such that the untrained output x = 0 gives 0.22 (BenchMARL's
#: default "biased_softplus_1.0": 1 at x = 0, floor 0.01): the floor keeps exploring where the default's scale
#: collapses and the curve flattens at the reference (docs results.md, "What was tried"). Off-policy: lr 3e-4.
#: Per task (``tasks``; a task's ``algorithm`` fields update its kind's): on ``saturated-v2`` the on-policy lr
#: is 3e-4, since at 1e-3 MAPPO reached 0.002 to 0.034 by 448k frames and then collapsed in all three seeds
#: (1.3 to 1.7 at 1,024k; docs results.md). On ``generalist-v2`` GAE's ``lmbda`` is 1 (BenchMARL's default
#: 0.9): the advantage is then the return to go less the critic's value, so IPPO's one-agent critic, which
#: cannot tell a directed path from a ring, is only a baseline and no longer biases the gradient through its
#: bootstrapped values (IPPO at 3e-4 with the task's reward floor: 0.285 over three seeds at lmbda 1, seed 0
#: 0.599 at 0.95); and the on-policy lr is 1e-4, since at 3e-4 with lmbda 1 MAPPO drifted up late (0.365). Docs
#: results.md, "IPPO on generalist-v2".
SETTINGS: dict[int, dict[str, Any]] = {
    1: {},
    2: {
        "gamma": 1.0,
        "episodes_per_batch": 64,
        "on_policy_n_minibatch_iters": 4,
        "on_policy_minibatch_size": 400,
        "off_policy_n_optimizer_steps": 50,
        "off_policy_train_batch_size": 256,
        "num_cells": (64, 64),
        "on_policy": {"lr": 1e-3, "algorithm": {"scale_mapping": "biased_softplus_0.22_0.1"}},
        "off_policy": {"lr": 3e-4, "algorithm": {}},
        "tasks": {
            "saturated-v2": {"on_policy": {"lr": 3e-4}},
            "generalist-v2": {"on_policy": {"lr": 1e-4, "algorithm": {"lmbda": 1.0}}},
        },
    },
}
#: The keys of a version's :data:`SETTINGS` that are not fields of BenchMARL's ``ExperimentConfig``.
_NOT_EXPERIMENT_FIELDS = ("num_cells", "on_policy", "off_policy", "episodes_per_batch", "tasks")


def kind_settings(task: NamedTask, algorithm: str) -> dict[str, Any]:
    """The task version's settings of ``algorithm``'s kind (``lr``, ``algorithm``: config fields), with the task's
    own where :data:`SETTINGS` gives them (``tasks``: its fields update the kind's); no ``lr`` and no fields for v1."""
    version, kind = SETTINGS[task.version], "off_policy" if algorithm in OFF_POLICY else "on_policy"
    common, own = version.get(kind, {}), version.get("tasks", {}).get(task.id, {}).get(kind, {})
    return {**common, **own, "algorithm": {**common.get("algorithm", {}), **own.get("algorithm", {})}}


def score_actor(task: NamedTask, act: Any) -> dict[str, list[float]]:
    """``act`` (``(S, N, obs) -> (S, N, action)`` arrays) on the task's evaluation episodes, as the suite plays them."""
    config = make_config(**scored_settings(task))
    stream = np.random.default_rng([*task.eval_seeds, config.n_intervals])  # the suite's stream
    with np.errstate(all="ignore"):
        metrics = seeded_metrics(config, act, task.eval_seeds, stream)
    errors = metrics["relative_deadline_error"]
    return {
        "deadline_error": np.where(np.isfinite(errors), errors, np.inf).tolist(),
        "energy": metrics["energy"].tolist(),
    }


def untrained_rows(task: NamedTask) -> dict[str, dict[str, list[float]]]:
    """The ``zero`` row (every action 0: the agents coast) and the ``random`` row (actions uniform over the task's
    box ``±action_bound``, drawn from ``np.random.default_rng(RANDOM_SEED)``), scored by :func:`score_actor`."""
    config = make_config(**scored_settings(task))
    bound, rng = config.action_bound, np.random.default_rng(RANDOM_SEED)

    def zero(obs: np.ndarray) -> np.ndarray:
        return np.zeros((*obs.shape[:2], config.action_size))

    def uniform(obs: np.ndarray) -> np.ndarray:
        return rng.uniform(-bound, bound, (*obs.shape[:2], config.action_size))

    return {"zero": score_actor(task, zero), "random": score_actor(task, uniform)}


class _Curve:
    """BenchMARL callback (made a subclass of its ``Callback`` by :func:`curve_callback`): scores the actor at
    the checkpoints and times collection, updates and its own scoring."""

    def __init__(self, task: NamedTask, frames: int, hidden: tuple[int, int] | None) -> None:
        self.task, self.frames, self.hidden = task, frames, hidden
        self.checkpoints = [frames * (k + 1) / CURVE_POINTS for k in range(CURVE_POINTS)]
        self.points: list[dict[str, Any]] = []
        self.seconds = {"collection": 0.0, "update": 0.0, "evaluation": 0.0}
        self.clock = time.perf_counter()

    def score(self, frames: int) -> None:
        """Score the experiment's deterministic actor now, as the curve's point at ``frames``."""
        start = time.perf_counter()
        act = policy_actor(self.experiment.policy, self.hidden)  # type: ignore[attr-defined]
        self.points.append({"frames": int(frames), **score_actor(self.task, act)})
        self.seconds["evaluation"] += time.perf_counter() - start

    def on_setup(self) -> None:
        self.clock = time.perf_counter()

    def on_batch_collected(self, batch: Any) -> None:
        now = time.perf_counter()
        self.seconds["collection"] += now - self.clock
        self.clock = now

    def on_train_end(self, training_td: Any, group: str) -> None:
        self.seconds["update"] += time.perf_counter() - self.clock
        done = int(self.experiment.total_frames)  # type: ignore[attr-defined]
        if self.checkpoints and (done >= self.checkpoints[0] or done >= self.frames):
            self.checkpoints = [c for c in self.checkpoints if c > done]
            self.score(done)
        self.clock = time.perf_counter()


def curve_callback(task: NamedTask, frames: int, hidden: tuple[int, int] | None) -> Any:
    """A BenchMARL ``Callback`` recording the run's learning curve and its cost (see the module)."""
    from benchmarl.experiment.callback import Callback

    return type("LearningCurve", (_Curve, Callback), {})(task, frames, hidden)


def train_and_score(task: NamedTask, algorithm: str, seed: int, frames: int, folder: Path) -> dict[str, Any]:
    """One BenchMARL run of ``algorithm`` on ``task`` for ``frames`` frames: its record with the trained actor's
    scores (:func:`score_actor`), its learning curve (``curve``: ``frames``, ``deadline_error``, ``energy`` per
    point, the first at 0 frames, the last the trained actor's) and its cost (``seconds``, ``frames_per_second``)."""
    experiment, actor = build_experiment(task, algorithm, seed, frames, folder)
    hidden = (actor.n_layers, actor.hidden_size) if actor.is_rnn else None
    curve = curve_callback(task, frames, hidden)
    curve.experiment = experiment
    curve.score(0)  # the untrained deterministic actor: scoring draws no random number from torch
    experiment.callbacks.append(curve)
    start = time.perf_counter()
    experiment.run()
    seconds = {**curve.seconds, "wall": time.perf_counter() - start}
    trained = curve.points[-1]
    return {**result_record(task), "algorithm": algorithm, "seed": seed, "frames": int(experiment.total_frames),
            "deadline_error": trained["deadline_error"], "energy": trained["energy"], "curve": curve.points,
            "seconds": seconds,
            "frames_per_second": experiment.total_frames / max(seconds["collection"] + seconds["update"], 1e-9)}  # fmt: skip


def policy_actor(policy: Any, hidden: tuple[int, int] | None = None) -> Any:
    """A BenchMARL policy as ``act(obs)`` for :func:`score_actor`, deterministic.

    A recurrent actor (``is_init`` and ``("agents", "_hidden_gru_0")`` in its ``in_keys``) carries its hidden
    state from step to step, from zeros with ``is_init`` true at the first, as BenchMARL's collector does.
    """
    import torch
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    hidden_keys = [key for key in policy.in_keys if hidden and isinstance(key, tuple) and key[-1].startswith("_hidden")]
    carried: dict[Any, Any] = {}

    def act(obs: np.ndarray) -> np.ndarray:
        b, n = obs.shape[:2]
        observation = torch.as_tensor(obs, dtype=torch.float32)
        td = TensorDict({"agents": TensorDict({"observation": observation}, batch_size=(b, n))}, batch_size=(b,))
        if hidden_keys:
            td.set("is_init", torch.full((b, 1), not carried, dtype=torch.bool))
            for key in hidden_keys:
                td.set(key, carried.get(key, torch.zeros((b, n, *hidden))))
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            out = policy(td)
        for key in hidden_keys:
            carried[key] = out.get(("next", *key))
        return out.get(("agents", "action")).double().numpy()

    return act


def build_experiment(task: NamedTask, algorithm: str, seed: int, frames: int, folder: Path) -> tuple[Any, Any]:
    """BenchMARL's ``Experiment`` of ``algorithm`` on ``task`` (not yet run) and its actor's model config."""
    from benchmarl import algorithms as benchmarl_algorithms
    from benchmarl.experiment import Experiment
    from benchmarl.models import GnnConfig, GruConfig, MlpConfig

    from fxc_env.envs.benchmarl_task import FxcTask

    algorithm_config, model = ALGORITHMS[algorithm]
    algorithm_settings = getattr(benchmarl_algorithms, algorithm_config).get_from_yaml()
    for name, value in kind_settings(task, algorithm)["algorithm"].items():
        setattr(algorithm_settings, name, value)
    if model == "gnn":
        import torch_geometric

        actor = GnnConfig(topology="full", self_loops=False, gnn_class=torch_geometric.nn.conv.GATv2Conv, gnn_kwargs={})
    else:
        # gru: BenchMARL's GRU (128 hidden units, one layer) and its MLP head
        actor = GruConfig.get_from_yaml() if model == "gru" else _mlp(MlpConfig, task)
    member = FxcTask[task.id.replace("-", "_").upper()]
    experiment = Experiment(
        task=member.get_from_yaml(),
        algorithm_config=algorithm_settings,
        model_config=actor,
        critic_model_config=_mlp(MlpConfig, task),
        seed=seed,
        config=experiment_config(task, algorithm, frames, folder),
    )
    return experiment, actor


def _mlp(mlp_config: Any, task: NamedTask) -> Any:
    """BenchMARL's MLP config with the task version's ``num_cells`` (its layer sizes) where :data:`SETTINGS` sets them."""
    config = mlp_config.get_from_yaml()
    if "num_cells" in SETTINGS[task.version]:
        config.num_cells = list(SETTINGS[task.version]["num_cells"])
    return config


def experiment_config(task: NamedTask, algorithm: str, frames: int, folder: Path) -> Any:
    """BenchMARL's experiment config on the CPU for ``frames`` frames with the task version's :data:`SETTINGS`
    (and ``lr`` of ``algorithm``'s kind); batches no larger than the budget."""
    from benchmarl.experiment import ExperimentConfig

    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = frames
    version = SETTINGS[task.version]
    settings = {name: value for name, value in version.items() if name not in _NOT_EXPERIMENT_FIELDS}
    if "lr" in kind_settings(task, algorithm):
        settings["lr"] = kind_settings(task, algorithm)["lr"]
    if "episodes_per_batch" in version:
        episodes = version["episodes_per_batch"]
        config.on_policy_n_envs_per_worker = config.off_policy_n_envs_per_worker = episodes
        config.on_policy_collected_frames_per_batch = episodes * task.n_intervals
        config.off_policy_collected_frames_per_batch = episodes * task.n_intervals
    for name, value in settings.items():
        setattr(config, name, value)
    _shrink_to_budget(config, task, frames)
    config.evaluation = config.create_json = config.render = config.checkpoint_at_end = False
    config.loggers = []
    folder.mkdir(parents=True, exist_ok=True)
    config.save_folder = str(folder)
    return config


def _shrink_to_budget(config: Any, task: NamedTask, frames: int) -> None:
    """Batches no larger than ``frames``: fewer environments (whole episodes where the budget allows), and as many
    off-policy updates per frame as the unshrunk batch had."""
    envs = max(1, min(config.on_policy_n_envs_per_worker, frames // task.n_intervals))
    batch = max(envs, min(config.on_policy_collected_frames_per_batch, frames) // envs * envs)
    steps_per_frame = config.off_policy_n_optimizer_steps / config.off_policy_collected_frames_per_batch
    config.off_policy_n_optimizer_steps = max(1, round(steps_per_frame * batch))
    config.on_policy_n_envs_per_worker = config.off_policy_n_envs_per_worker = envs
    config.on_policy_collected_frames_per_batch = config.off_policy_collected_frames_per_batch = batch
    config.on_policy_minibatch_size = min(config.on_policy_minibatch_size, batch)
    config.off_policy_train_batch_size = min(config.off_policy_train_batch_size, batch)
    config.off_policy_init_random_frames = min(config.off_policy_init_random_frames, frames // 2)
