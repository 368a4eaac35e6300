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
from fxc_env.baselines.harness.benchmark import make_out, run_benchmark
from fxc_env.baselines.harness.suite import builtin_contenders, learned_contender
from fxc_env.config.tasks import TASKS, NamedTask, get_task
from fxc_env.core.validation import ArgumentError, integer
from fxc_env.policies.learned import SHIPPED
from fxc_env.training.evaluation import statistics
from fxc_env.training.evaluation.evaluate import on_task_schedule, task_suite
from fxc_env.training.evaluation.leaderboard_files import (
    cost_lines,
    curve_figure,
    laws_problem,
    marl_eval_record,
    profile_figure,
    result_commits,
    result_record,
    run_problem,
    versions,
    write_json,
)
from fxc_env.training.evaluation.leaderboard_runs import (  # noqa: F401  (build_experiment, policy_actor, score_actor: the API)
    ALGORITHMS,
    build_experiment,
    policy_actor,
    score_actor,
    train_and_score,
    untrained_rows,
)
from fxc_env.training.evaluation.seed_evaluation import LOG_FLOOR
from fxc_env.training.evaluation.statistics import DEFAULT_BOOTSTRAP_SEED, DEFAULT_REPS
from fxc_env.utils.cli_checks import output_directory

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
#: The rows that need no training: the zero action and uniform random actions over the box (seeded).
UNTRAINED = ("zero", "random")
#: Every shipped learned policy (``pretrained`` is the generalist under another name).
SHIPPED_POLICIES = tuple(name for name in SHIPPED if name != "pretrained")


def add_leaderboard_parser(commands: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``fxc leaderboard``."""
    parser = commands.add_parser(
        "leaderboard",
        help="BenchMARL's algorithms beside the analytic laws and shipped policies on the named tasks",
        description="Train BenchMARL's MAPPO, IPPO, MASAC, MADDPG (MLP) and MAPPO with a GNN and a GRU on the named tasks "
        "(same frame budget, several training seeds), score them with the laws and shipped policies on each "
        "task's evaluation seeds by D(T_s)/D(0) beside the zero action, uniform random actions and each algorithm untrained "
        "(<algorithm>@0), and write table.md (with each algorithm's training cost), marl_eval.json, "
        "performance_profile.png, curves_<task>.png (learning curves) and versions.json. "
        "Finished runs are kept under --out: a rerun resumes.",
    )
    parser.add_argument(
        "--frames",
        nargs="+",
        default=[str(SHIPPED_FRAMES)],
        metavar="FRAMES [ALGORITHM=FRAMES]",
        help=f"frames per training run ({SHIPPED_FRAMES}: the shipped v1 table, about 11 CPU-minutes in all; "
        "training time grows linearly with it), then ALGORITHM=FRAMES for an algorithm that differs "
        "(the shipped v2 table: 1024000 masac=64000 maddpg=64000)",
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


def check_budget(args: argparse.Namespace, algorithms: list[str]) -> tuple[dict[str, int], int]:
    """``--frames`` (one budget, then ``ALGORITHM=FRAMES`` for an algorithm of ``algorithms`` that differs) as
    each algorithm's budget, and ``--seeds``, each bounded (:data:`MAX_FRAMES`, :data:`MAX_SEEDS`)."""
    values = args.frames if isinstance(args.frames, list) else [args.frames]
    budget = {"": _frames(values[0])}
    for value in values[1:]:
        algorithm, equals, frames = str(value).partition("=")
        if not equals or algorithm not in algorithms or algorithm in budget:
            raise ArgumentError(
                f"--frames: after the budget, expected ALGORITHM=FRAMES, once each, for one of --algorithms "
                f"{tuple(algorithms)}, got {value!r}"
            )
        budget[algorithm] = _frames(frames)
    frames = {algorithm: budget.get(algorithm, budget[""]) for algorithm in algorithms}
    return frames, integer("--seeds", args.seeds, 1, MAX_SEEDS)


def _frames(text: Any) -> int:
    """One ``--frames`` number (digits as given on the command line, or an int)."""
    return integer("--frames", int(text) if isinstance(text, str) and text.isdigit() else text, 1, MAX_FRAMES)


def refuse_unread_budget(args: argparse.Namespace, algorithms: list[str]) -> None:
    """``--frames`` or ``--seeds`` given with ``--algorithms none``, which trains nothing, is refused by name."""
    for flag in ("frames", "seeds"):
        if not algorithms and flag in getattr(args, "given_flags", set()):
            raise ArgumentError(
                f"--{flag}: only BenchMARL's algorithms read it, and --algorithms none trains nothing; leave it out"
            )


def leaderboard_command(args: argparse.Namespace) -> int:
    """Handler of ``fxc leaderboard``: every value and every file kept under ``--out`` is checked before any run
    starts (:mod:`fxc_env.training.evaluation.leaderboard_files`)."""
    named = [] if list(args.algorithms) == ["none"] else list(dict.fromkeys(args.algorithms))
    frames, seeds = check_budget(args, named)
    reps = integer("--bootstrap-reps", args.bootstrap_reps, 1)
    tasks = check_tasks(list(args.tasks))
    algorithms = check_algorithms(list(args.algorithms))
    refuse_unread_budget(args, algorithms)
    out = output_directory("--out", args.out)
    rescore, train = plan_files(out, tasks, algorithms, seeds, frames, scored_names())
    for task in tasks:
        make_out(out / task.id)
    for task in (task for task in tasks if task.id in rescore):
        if rescore[task.id]:
            print(f"fxc leaderboard: scoring {out / task.id / 'laws.json'} again: it {rescore[task.id]}", flush=True)
        write_json(out / task.id / "laws.json", score_laws(task, out / task.id / "benchmark"))
    for task, algorithm, seed in train:
        print(f"fxc leaderboard: {task.id}: {algorithm}, seed {seed}, {frames[algorithm]} frames", flush=True)
        folder = out / task.id / algorithm
        run = train_and_score(task, algorithm, seed, frames[algorithm], folder / f"seed{seed}")
        write_json(folder / f"seed{seed}.json", run)
    table, files = write_leaderboard(out, tasks, algorithms, seeds, reps)
    print(table)
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def plan_files(
    out: Path, tasks: list[NamedTask], algorithms: list[str], seeds: int, frames: dict[str, int], contenders: list[str]
) -> tuple[dict[str, str], list[tuple[NamedTask, str, int]]]:
    """What a run under ``out`` does: the tasks (ids) whose ``laws.json`` is (re)scored, with why ("" when there is
    none yet), and the training runs still to do (``frames``: each algorithm's budget). A kept run that does not
    match the request is refused."""
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
                elif (recorded := json.loads(path.read_text())["frames"]) != frames[algorithm]:
                    raise ArgumentError(
                        f"--frames: {path} was trained for {recorded} frames, not {frames[algorithm]}; "
                        "give the same budget to resume, or another --out"
                    )
    return rescore, train


# ------------------------------------------------------------------------------- scoring
def law_contenders(learned: dict[str, Any] | None = None) -> list[Any]:
    """The laws and the shipped policies, as the benchmark's contenders; on a task, ``learned`` (the task's
    schedule and modes, :func:`~fxc_env.training.evaluation.evaluate.task_suite`) is what the shipped policies run with, as
    ``fxc evaluate --task`` runs them, and a schedule it fixes is every law's too."""
    learned = learned or {}
    laws = on_task_schedule(builtin_contenders(list(LAWS)), learned)
    return laws + [learned_contender(name, name=name, **learned) for name in SHIPPED_POLICIES]


def scored_names() -> list[str]:
    """What ``<task>/laws.json`` scores: the zero action, uniform random actions, the laws and the shipped policies."""
    return [*UNTRAINED, *(contender.name for contender in law_contenders())]


def score_laws(task: NamedTask, folder: Path) -> dict[str, Any]:
    """The deadline errors and energies on the task's evaluation episodes of the zero action and uniform random
    actions (:func:`~fxc_env.training.evaluation.leaderboard_runs.untrained_rows`), the laws and the shipped policies."""
    suite, learned = task_suite(task)
    contenders = law_contenders(learned)
    output = run_benchmark(suite, contenders, folder, workers=1, progress=False)
    scores: dict[str, Any] = untrained_rows(task)
    for result in output.results:
        name = result.job.contender.name
        if result.error is not None:
            scores[name] = {"note": result.error}
        else:
            scores[name] = {
                "deadline_error": result.metrics["relative_deadline_error"].tolist(),
                "energy": result.metrics["energy"].tolist(),
            }
    return {**result_record(task), "contenders": scored_names(), "scores": scores}


# ------------------------------------------------------------------------------- the table
def write_leaderboard(
    out: Path, tasks: list[NamedTask], algorithms: list[str], seeds: int, reps: int
) -> tuple[str, list[Path]]:
    """``table.md`` (the scores, then each algorithm's training cost), ``marl_eval.json``,
    ``performance_profile.png``, ``versions.json`` and one ``curves_<task>.png`` per task (with algorithms) from
    the files under ``out``."""
    names, scores, energies, runs = _collect(out, tasks, algorithms, seeds)
    lines = _score_lines(names, scores, tasks, reps)
    command = "fxc " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["leaderboard"] else None
    intro = (
        "Leaderboard: "
        + (
            f"{len(algorithms)} BenchMARL algorithms x {seeds} training seeds (`<algorithm>@0`: the same actors "
            "untrained), "
            if algorithms
            else ""
        )
        + f"the zero action, uniform random actions, the laws and the shipped policies, on "
        f"{', '.join(t.full_id for t in tasks)}; each scored on its task's evaluation seeds "
        f"(95% stratified bootstrap, {reps} replicates; log10 floored at {LOG_FLOOR:g})."
        + (f"\nCommand: `{command}`" if command else "")
    )
    headline = headline_lines(tasks, algorithms, scores)
    table = intro + "\n\n" + "\n".join(lines) + "\n" + ("\n" + "\n".join(headline) + "\n" if headline else "")
    if algorithms:
        table += "\n" + "\n".join(cost_lines(runs)) + "\n"
    files = [out / "table.md", out / "marl_eval.json", out / "performance_profile.png", out / "versions.json"]
    files[0].write_text(table)
    write_json(files[1], marl_eval_record(scores, energies, [task.id for task in tasks], seeds if algorithms else 1))
    profile_figure(scores, tuple(ALGORITHMS) + tuple(f"{name}@0" for name in ALGORITHMS), files[2])
    write_json(files[3], {**versions(), "result_commits": result_commits(out, tasks, algorithms, seeds)})
    for task in tasks if algorithms else []:
        files.append(out / f"curves_{task.id}.png")
        baselines = {name: scores[name][task.id] for name in ("zero", "reference") if task.id in scores.get(name, {})}
        curve_figure(task.id, runs[task.id], baselines, files[-1])
    return table, files


def _score_lines(
    names: list[str], scores: dict[str, dict[str, np.ndarray]], tasks: list[NamedTask], reps: int
) -> list[str]:
    """The score table's markdown lines: per contender and task, the median and the IQM of log10 with intervals."""
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
    return lines


def _collect(out: Path, tasks: list[NamedTask], algorithms: list[str], seeds: int) -> tuple[
    list[str], dict[str, dict[str, np.ndarray]], dict[str, dict[str, np.ndarray]], dict[str, dict[str, list[Any]]]
]:  # fmt: skip
    """The contenders in table order; per contender and task the (runs, episodes) errors and energies; per task and
    algorithm the training runs' records (seed order). ``<algorithm>@0``: the first point of each run's curve."""
    scores: dict[str, dict[str, np.ndarray]] = {}
    energies: dict[str, dict[str, np.ndarray]] = {}
    records: dict[str, dict[str, list[Any]]] = {}
    names = list(algorithms) + [f"{algorithm}@0" for algorithm in algorithms]
    for task in tasks:
        laws = json.loads((out / task.id / "laws.json").read_text())
        names += [name for name in laws["contenders"] if name not in names]
        for name, record in laws["scores"].items():
            if "note" not in record:  # a refused contender: its reason stays in laws.json
                scores.setdefault(name, {})[task.id] = np.array([record["deadline_error"]])
                energies.setdefault(name, {})[task.id] = np.array([record["energy"]])
        for algorithm in algorithms:
            runs = [json.loads((out / task.id / algorithm / f"seed{k}.json").read_text()) for k in range(seeds)]
            records.setdefault(task.id, {})[algorithm] = runs
            for name, points in ((algorithm, runs), (f"{algorithm}@0", [run["curve"][0] for run in runs])):
                scores.setdefault(name, {})[task.id] = np.array([point["deadline_error"] for point in points])
                energies.setdefault(name, {})[task.id] = np.array([point["energy"] for point in points])
    return names, {name: scores[name] for name in names if name in scores}, energies, records  # table order


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
                     f"{_number(float(np.median(reference)))}: {verdict} (best of all: {top} {_number(overall[top])})"
                     + "".join(f"; {name} {_number(overall[name])}" for name in (f"{best}@0", "zero") if name in overall))  # fmt: skip
    return lines


def _number(value: float) -> str:
    return "∞" if math.isinf(value) else f"{value:.3g}"
