"""``fxc leaderboard``: BenchMARL's algorithms beside the analytic laws and the shipped policies on the named tasks.

For every task of :data:`fxc_env.config.tasks.TASKS` (or those named) every algorithm trains for the same frame
budget on each training seed; the laws, the shipped policies and the trained actors are scored on the task's
frozen evaluation seeds (median and IQM of log10 ``D(T_s)/D(0)``, bootstrap intervals). Every finished piece is
a file under ``--out`` that a rerun skips. Training needs BenchMARL (the ``[benchmarl]`` extra); ``--algorithms
none`` scores the laws and the shipped policies only (docs: results.md, "MARL algorithms table").
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.baselines import registry
from fxc_env.baselines.benchmark import make_out, run_benchmark
from fxc_env.baselines.suite import builtin_contenders, learned_contender
from fxc_env.config import make_config
from fxc_env.config.tasks import TASKS, NamedTask, get_task
from fxc_env.core import statistics
from fxc_env.core.statistics import DEFAULT_BOOTSTRAP_SEED, DEFAULT_REPS
from fxc_env.core.validation import ArgumentError, integer
from fxc_env.engine import ConsensusEngine
from fxc_env.policies.learned import SHIPPED
from fxc_env.training.evaluate import on_task_schedule, scored_settings, task_suite
from fxc_env.training.leaderboard_files import (
    laws_problem,
    marl_eval_record,
    profile_figure,
    result_commits,
    result_record,
    run_problem,
    versions,
    write_json,
)
from fxc_env.training.seed_evaluation import LOG_FLOOR
from fxc_env.utils.cli_checks import output_directory

#: BenchMARL's algorithms in the table: (algorithm config, actor model). MADDPG is the deterministic one.
ALGORITHMS = {
    "mappo": ("MappoConfig", "mlp"),
    "ippo": ("IppoConfig", "mlp"),
    "masac": ("MasacConfig", "mlp"),
    "maddpg": ("MaddpgConfig", "mlp"),
    "mappo_gnn": ("MappoConfig", "gnn"),
    "mappo_gru": ("MappoConfig", "gru"),
}
#: The frame budget per run of the shipped table (fxc_env/assets/leaderboard/): the whole table took 11 CPU-minutes.
SHIPPED_FRAMES = 1000
#: Most frames per training run (at the shipped table's rate, about 9 CPU-seconds per 1,000 frames, some 11
#: CPU-days a run) and most training seeds per algorithm.
MAX_FRAMES = 10**8
MAX_SEEDS = 100
#: The analytic laws beside them (fxc_env.baselines).
LAWS = tuple(name for name, law in registry.LAWS.items() if law.leaderboard)
#: The tasks of the shipped table (fxc_env/assets/leaderboard/), ``--tasks``' default: the v1 tasks.
SHIPPED_TASKS = tuple(task.id for task in TASKS.values() if task.version == 1)
#: Every shipped learned policy (``pretrained`` is the generalist under another name).
SHIPPED_POLICIES = tuple(name for name in SHIPPED if name != "pretrained")


def add_leaderboard_parser(commands: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``fxc leaderboard``."""
    parser = commands.add_parser(
        "leaderboard",
        help="BenchMARL's algorithms beside the analytic laws and shipped policies on the named tasks",
        description="Train BenchMARL's MAPPO, IPPO, MASAC, MADDPG (MLP) and MAPPO with a GNN and a GRU on the named tasks "
        "(same frame budget, several training seeds), score them with the laws and shipped policies on each "
        "task's evaluation seeds by D(T_s)/D(0), and write table.md, marl_eval.json, performance_profile.png and versions.json. "
        "Finished runs are kept under --out: a rerun resumes.",
    )
    parser.add_argument(
        "--frames",
        type=int,
        default=SHIPPED_FRAMES,
        help=f"frames per training run ({SHIPPED_FRAMES}: the shipped table, about 11 CPU-minutes in all; "
        "training time grows linearly with it)",
    )
    parser.add_argument("--seeds", type=int, default=3, help="training seeds per algorithm (3: seeds 0, 1, 2)")
    parser.add_argument(
        "--tasks",
        nargs="+",
        default=list(SHIPPED_TASKS),
        help=f"named tasks (default: the v1 tasks, the shipped table's; all: {' '.join(TASKS)})",
    )
    parser.add_argument(
        "--algorithms",
        nargs="+",
        default=list(ALGORITHMS),
        help=f"BenchMARL algorithms ({' '.join(ALGORITHMS)}; 'none': the laws and shipped policies only)",
    )
    parser.add_argument("--out", default="out/leaderboard", help="directory of the runs, table and figure")
    parser.add_argument(
        "--bootstrap-reps", type=int, default=DEFAULT_REPS, help=f"bootstrap replicates ({DEFAULT_REPS})"
    )
    parser.set_defaults(handler=leaderboard_command)
    return parser


def has_benchmarl() -> bool:
    """Whether BenchMARL imports (its ``experiment`` module: a folder named ``benchmarl`` is not it)."""
    try:
        importlib.import_module("benchmarl.experiment")
    except ModuleNotFoundError:
        return False
    return True


def check_algorithms(names: list[str]) -> list[str]:
    """The algorithms asked for; BenchMARL's are refused, naming what to install, where it is missing."""
    if names == ["none"]:
        return []
    unknown = [name for name in names if name not in ALGORITHMS]
    if unknown:
        raise ArgumentError(f"--algorithms: expected some of {tuple(ALGORITHMS)} or 'none', got {unknown[0]!r}")
    if not has_benchmarl():
        raise ArgumentError(
            f"--algorithms: {', '.join(names)} train with BenchMARL, which this environment lacks: run in "
            '.venv-benchmarl (make benchmarl) or pip install "fxc-env[benchmarl]"; '
            "--algorithms none scores the laws and shipped policies only"
        )
    return list(dict.fromkeys(names))


def check_tasks(names: list[str]) -> list[NamedTask]:
    """The named tasks, in order; a task named twice (``rings20-v1`` and ``fxc/rings20-v1`` alike) is refused."""
    tasks: dict[str, NamedTask] = {}
    for name in names:
        task = get_task(name, "--tasks")
        if task.id in tasks:
            raise ArgumentError(f"--tasks: {task.id} is named twice; name each task once")
        tasks[task.id] = task
    return list(tasks.values())


def check_budget(args: argparse.Namespace) -> tuple[int, int]:
    """``--frames`` and ``--seeds``, each bounded (:data:`MAX_FRAMES`, :data:`MAX_SEEDS`)."""
    return integer("--frames", args.frames, 1, MAX_FRAMES), integer("--seeds", args.seeds, 1, MAX_SEEDS)


def refuse_unread_budget(args: argparse.Namespace, algorithms: list[str]) -> None:
    """``--frames`` or ``--seeds`` given with ``--algorithms none``, which trains nothing, is refused by name."""
    for flag in ("frames", "seeds"):
        if not algorithms and flag in getattr(args, "given_flags", set()):
            raise ArgumentError(
                f"--{flag}: only BenchMARL's algorithms read it, and --algorithms none trains nothing; leave it out"
            )


def leaderboard_command(args: argparse.Namespace) -> int:
    """Handler of ``fxc leaderboard``: every value and every file kept under ``--out`` is checked before any run
    starts (:mod:`fxc_env.training.leaderboard_files`)."""
    frames, seeds = check_budget(args)
    reps = integer("--bootstrap-reps", args.bootstrap_reps, 1)
    tasks = check_tasks(list(args.tasks))
    algorithms = check_algorithms(list(args.algorithms))
    refuse_unread_budget(args, algorithms)
    out = output_directory("--out", args.out)
    contenders = [contender.name for contender in law_contenders()]
    rescore, train = plan_files(out, tasks, algorithms, seeds, frames, contenders)
    for task in tasks:
        make_out(out / task.id)
    for task in (task for task in tasks if task.id in rescore):
        if rescore[task.id]:
            print(f"fxc leaderboard: scoring {out / task.id / 'laws.json'} again: it {rescore[task.id]}", flush=True)
        write_json(out / task.id / "laws.json", score_laws(task, out / task.id / "benchmark"))
    for task, algorithm, seed in train:
        print(f"fxc leaderboard: {task.id}: {algorithm}, seed {seed}, {frames} frames", flush=True)
        folder = out / task.id / algorithm
        write_json(folder / f"seed{seed}.json", train_and_score(task, algorithm, seed, frames, folder / f"seed{seed}"))
    table, files = write_leaderboard(out, tasks, algorithms, seeds, reps)
    print(table)
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def plan_files(
    out: Path, tasks: list[NamedTask], algorithms: list[str], seeds: int, frames: int, contenders: list[str]
) -> tuple[dict[str, str], list[tuple[NamedTask, str, int]]]:
    """What a run under ``out`` does: the tasks (ids) whose ``laws.json`` is (re)scored, with why ("" when there is
    none yet), and the training runs still to do. A kept run that does not match the request is refused."""
    rescore: dict[str, str] = {}
    train = []
    for task in tasks:
        laws = out / task.id / "laws.json"
        if not laws.exists():
            rescore[task.id] = ""
        elif why := laws_problem(laws, task, contenders):
            rescore[task.id] = why
        for algorithm in algorithms:
            for seed in range(seeds):
                path = out / task.id / algorithm / f"seed{seed}.json"
                if not path.exists():
                    train.append((task, algorithm, seed))
                elif why := run_problem(path, task, algorithm, seed):
                    raise ArgumentError(
                        f"--out: {path} {why}; delete it to train and score that run again, or give another --out"
                    )
                elif (recorded := json.loads(path.read_text())["frames"]) != frames:
                    raise ArgumentError(
                        f"--frames: {path} was trained for {recorded} frames, not {frames}; "
                        "give the same budget to resume, or another --out"
                    )
    return rescore, train


# ------------------------------------------------------------------------------- scoring
def law_contenders() -> list[Any]:
    """The laws and the shipped policies, as the benchmark's contenders."""
    return builtin_contenders(list(LAWS)) + [learned_contender(name, name=name) for name in SHIPPED_POLICIES]


def score_laws(task: NamedTask, folder: Path) -> dict[str, Any]:
    """The laws' and the shipped policies' deadline errors and energies on the task's evaluation episodes."""
    suite, learned = task_suite(task)
    contenders = on_task_schedule(law_contenders(), learned)
    output = run_benchmark(suite, contenders, folder, workers=1, progress=False)
    scores: dict[str, Any] = {}
    for result in output.results:
        name = result.job.contender.name
        if result.error is not None:
            scores[name] = {"note": result.error}
        else:
            scores[name] = {
                "deadline_error": result.metrics["relative_deadline_error"].tolist(),
                "energy": result.metrics["energy"].tolist(),
            }
    return {**result_record(task), "contenders": [c.name for c in contenders], "scores": scores}


def score_actor(task: NamedTask, act: Any) -> dict[str, list[float]]:
    """``act`` (``(S, N, obs) -> (S, N, action)`` arrays) on the task's evaluation episodes, as the suite plays them."""
    config = make_config(**scored_settings(task))
    seeds = task.eval_seeds
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in seeds]
    engine.reset_from_draws(draws, rng=np.random.default_rng([*seeds, config.n_intervals]))  # the suite's stream
    obs = np.empty((engine.n_episodes, config.n_agents, config.layout.size))
    with np.errstate(all="ignore"):
        while not engine.done:
            engine.observations(out=obs)
            engine.step(np.asarray(act(obs), dtype=np.float64))
        metrics = engine.batch_metrics()
    errors = metrics["relative_deadline_error"]
    return {
        "deadline_error": np.where(np.isfinite(errors), errors, np.inf).tolist(),
        "energy": metrics["energy"].tolist(),
    }


def train_and_score(task: NamedTask, algorithm: str, seed: int, frames: int, folder: Path) -> dict[str, Any]:
    """One BenchMARL run of ``algorithm`` on ``task`` for ``frames`` frames, scored by :func:`score_actor`."""
    experiment, actor = build_experiment(task, algorithm, seed, frames, folder)
    experiment.run()
    hidden = (actor.n_layers, actor.hidden_size) if actor.is_rnn else None
    return {**result_record(task), "algorithm": algorithm, "seed": seed, "frames": int(experiment.total_frames),
            **score_actor(task, policy_actor(experiment.policy, hidden))}  # fmt: skip


def policy_actor(policy: Any, hidden: tuple[int, int] | None = None) -> Any:
    """A trained BenchMARL policy as ``act(obs)`` for :func:`score_actor`, deterministic.

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
    if model == "gnn":
        import torch_geometric

        actor = GnnConfig(topology="full", self_loops=False, gnn_class=torch_geometric.nn.conv.GATv2Conv, gnn_kwargs={})
    elif model == "gru":
        actor = GruConfig.get_from_yaml()  # BenchMARL's GRU (128 hidden units, one layer) and its MLP head
    else:
        actor = MlpConfig.get_from_yaml()
    member = FxcTask[task.id.replace("-", "_").upper()]
    experiment = Experiment(
        task=member.get_from_yaml(),
        algorithm_config=getattr(benchmarl_algorithms, algorithm_config).get_from_yaml(),
        model_config=actor,
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=seed,
        config=_experiment_config(task, frames, folder),
    )
    return experiment, actor


def _experiment_config(task: NamedTask, frames: int, folder: Path) -> Any:
    """BenchMARL's default experiment config on the CPU for ``frames`` frames: batches no larger than the budget."""
    from benchmarl.experiment import ExperimentConfig

    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.max_n_frames = frames
    envs = max(1, min(config.on_policy_n_envs_per_worker, frames // task.n_intervals))
    batch = max(envs, min(config.on_policy_collected_frames_per_batch, frames) // envs * envs)
    # A smaller batch keeps BenchMARL's off-policy updates per frame (1000 optimizer steps per 6000 frames).
    steps_per_frame = config.off_policy_n_optimizer_steps / config.off_policy_collected_frames_per_batch
    config.off_policy_n_optimizer_steps = max(1, round(steps_per_frame * batch))
    config.on_policy_n_envs_per_worker = config.off_policy_n_envs_per_worker = envs
    config.on_policy_collected_frames_per_batch = config.off_policy_collected_frames_per_batch = batch
    config.on_policy_minibatch_size = min(config.on_policy_minibatch_size, batch)
    config.off_policy_train_batch_size = min(config.off_policy_train_batch_size, batch)
    config.off_policy_init_random_frames = min(config.off_policy_init_random_frames, frames // 2)
    config.evaluation = config.create_json = config.render = config.checkpoint_at_end = False
    config.loggers = []
    folder.mkdir(parents=True, exist_ok=True)
    config.save_folder = str(folder)
    return config


# ------------------------------------------------------------------------------- the table
def write_leaderboard(
    out: Path, tasks: list[NamedTask], algorithms: list[str], seeds: int, reps: int
) -> tuple[str, list[Path]]:
    """``table.md``, ``marl_eval.json``, ``performance_profile.png`` and ``versions.json`` from the files under ``out``."""
    names, scores, energies = _collect(out, tasks, algorithms, seeds)
    header = ["contender"] + [f"{task.id}: median D(T_s)/D(0) [95% CI] / IQM log10 [95% CI]" for task in tasks]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for name in names:
        row = [name]
        for task in tasks:
            errors = scores.get(name, {}).get(task.id)
            if errors is None:
                row.append("not run (refused: the reason is in laws.json)")
                continue
            median = statistics.stratified_bootstrap(errors, "median", reps=reps, seed=DEFAULT_BOOTSTRAP_SEED)
            iqm = statistics.stratified_bootstrap(
                statistics.decades(errors, LOG_FLOOR), "iqm", reps=reps, seed=DEFAULT_BOOTSTRAP_SEED
            )
            row.append(f"{_number(median.estimate)} [{_number(median.low)}, {_number(median.high)}] / "
                       f"{iqm.estimate:.2f} [{iqm.low:.2f}, {iqm.high:.2f}]")  # fmt: skip
        lines.append("| " + " | ".join(row) + " |")
    command = "fxc " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["leaderboard"] else None
    intro = (
        "Leaderboard: "
        + (f"{len(algorithms)} BenchMARL algorithms x {seeds} training seeds, " if algorithms else "")
        + f"the laws and the shipped policies, on {', '.join(t.full_id for t in tasks)}; each scored on its task's evaluation seeds "
        f"(95% stratified bootstrap, {reps} replicates; log10 floored at {LOG_FLOOR:g})."
        + (f"\nCommand: `{command}`" if command else "")
    )
    headline = headline_lines(tasks, algorithms, scores)
    table = intro + "\n\n" + "\n".join(lines) + "\n" + ("\n" + "\n".join(headline) + "\n" if headline else "")
    files = [out / "table.md", out / "marl_eval.json", out / "performance_profile.png", out / "versions.json"]
    files[0].write_text(table)
    write_json(files[1], marl_eval_record(scores, energies, [task.id for task in tasks], seeds if algorithms else 1))
    profile_figure(scores, tuple(ALGORITHMS), files[2])
    write_json(files[3], {**versions(), "result_commits": result_commits(out, tasks, algorithms, seeds)})
    return table, files


def _collect(
    out: Path, tasks: list[NamedTask], algorithms: list[str], seeds: int
) -> tuple[list[str], dict[str, dict[str, np.ndarray]], dict[str, dict[str, np.ndarray]]]:
    """The contenders in table order, and per contender and task the (runs, episodes) errors and energies."""
    scores: dict[str, dict[str, np.ndarray]] = {}
    energies: dict[str, dict[str, np.ndarray]] = {}
    names = list(algorithms)
    for task in tasks:
        laws = json.loads((out / task.id / "laws.json").read_text())
        names += [name for name in laws["contenders"] if name not in names]
        for name, record in laws["scores"].items():
            if "note" not in record:  # a refused contender: its reason stays in laws.json
                scores.setdefault(name, {})[task.id] = np.array([record["deadline_error"]])
                energies.setdefault(name, {})[task.id] = np.array([record["energy"]])
        for algorithm in algorithms:
            runs = [json.loads((out / task.id / algorithm / f"seed{k}.json").read_text()) for k in range(seeds)]
            scores.setdefault(algorithm, {})[task.id] = np.array([run["deadline_error"] for run in runs])
            energies.setdefault(algorithm, {})[task.id] = np.array([run["energy"] for run in runs])
    return names, {name: scores[name] for name in names if name in scores}, energies  # table order: the legend's


def headline_lines(
    tasks: list[NamedTask], algorithms: list[str], scores: dict[str, dict[str, np.ndarray]]
) -> list[str]:
    """Per task, the best BenchMARL algorithm (lowest median D(T_s)/D(0)) against the paper's law (``reference``),
    in decades of the median (log10, floored at :data:`LOG_FLOOR`): where learning loses, and by how much."""
    if not algorithms:
        return []
    lines = ["Headline (median D(T_s)/D(0) over training seeds x evaluation episodes):"]
    for task in tasks:
        medians = {name: float(np.median(scores[name][task.id])) for name in algorithms}
        best = min(medians, key=medians.__getitem__)
        reference = scores.get("reference", {}).get(task.id)
        if reference is None:
            lines.append(
                f"- {task.id}: best algorithm {best} {_number(medians[best])}; the reference law is refused here"
            )
            continue
        gap = float(statistics.decades(medians[best], LOG_FLOOR) - statistics.decades(np.median(reference), LOG_FLOOR))
        verdict = (
            f"learning loses by {gap:.1f} decades" if gap > 0 else f"learning matches or beats it by {-gap:.1f} decades"
        )
        overall = {name: float(np.median(by_task[task.id])) for name, by_task in scores.items() if task.id in by_task}
        top = min(overall, key=overall.__getitem__)
        lines.append(f"- {task.id}: best algorithm {best} {_number(medians[best])} vs the paper's law (reference) "
                     f"{_number(float(np.median(reference)))}: {verdict} (best of all: {top} {_number(overall[top])})")  # fmt: skip
    return lines


def _number(value: float) -> str:
    return "∞" if math.isinf(value) else f"{value:.3g}"
