"""The files ``fxc leaderboard`` keeps under ``--out``, what each records, and the checks a rerun makes of them.

Every result file records what it was scored for: the task (``task``), its evaluation seeds (``seeds``),
the episode count (``episodes``), fxc_env's version (``fxc_env``) and git commit (``fxc_env_commit``: the
commits of a table's files are listed in its ``versions.json`` as ``result_commits``); a
training run also its algorithm, training seed and frame budget. A rerun keeps a file only where its record
matches the request and its scores are whole (one finite or ``inf`` deadline error and one energy per
episode): ``<task>/laws.json`` that does not is scored again (a line names the file and why), a training run
that does not is refused by name (only retraining could score it again). Docs: results.md, "MARL algorithms
table".
"""

from __future__ import annotations

import functools
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.config.tasks import NamedTask
from fxc_env.core.validation import short_repr
from fxc_env.training.evaluation import statistics
from fxc_env.training.evaluation.seed_scores import LOG_FLOOR, MARL_EVAL_ENV, marl_eval_entry

#: A training run's timers (``seconds``): collecting batches, updating the networks, scoring its learning curve
#: (not training), and ``Experiment.run``'s wall time (all three and BenchMARL's own bookkeeping).
TIMERS = ("collection", "update", "evaluation", "wall")
#: What a result file records besides its scores (see the module).
RECORD_FIELDS = ("task", "seeds", "episodes", "fxc_env", "fxc_env_commit")


def result_record(task: NamedTask) -> dict[str, Any]:
    """The record every result file of ``task`` carries (:data:`RECORD_FIELDS`)."""
    made = versions()
    return {"task": task.full_id, "seeds": list(task.eval_seeds), "episodes": len(task.eval_seeds),
            "fxc_env": made["fxc_env"], "fxc_env_commit": made["fxc_env_commit"]}  # fmt: skip


def read_result(path: Path) -> tuple[dict[str, Any] | None, str]:
    """The JSON object at ``path``, or None and why it cannot be read (damaged, not an object)."""
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        return None, f"cannot be read as JSON ({type(exc).__name__})"
    if not isinstance(record, dict):
        return None, f"holds a {type(record).__name__}, not a JSON object"
    return record, ""


def record_problem(record: dict[str, Any], task: NamedTask, expected: dict[str, Any]) -> str:
    """Why ``record`` does not match ``task`` scored now plus ``expected``'s entries ("" when it does).

    The commit is not compared (it changes with every commit of a checkout); the version is.
    """
    missing = [field for field in (*RECORD_FIELDS, *expected) if field not in record]
    if missing:
        return f"records no {', '.join(missing)} (written by hand or by an older fxc leaderboard)"
    wanted = {**{k: v for k, v in result_record(task).items() if k != "fxc_env_commit"}, **expected}
    for field, value in wanted.items():
        if record[field] != value:
            return f"records {field} {short_repr(record[field])}, not {short_repr(value)}"
    return ""


def scores_problem(record: Any, episodes: int) -> str:
    """Why ``record`` is not one score per episode ("" when it is): ``deadline_error`` a list of ``episodes``
    numbers >= 0 (``inf``: diverged), ``energy`` as many finite numbers >= 0."""
    if not isinstance(record, dict):
        return "holds no scores"
    for key, allow_inf in (("deadline_error", True), ("energy", False)):
        values = record.get(key)
        if not isinstance(values, list) or len(values) != episodes:
            return f"holds no {episodes} {key} values"
        for value in values:
            if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
                return f"holds a {key} of {value!r} (expected numbers >= 0)"
            if math.isinf(value) and not allow_inf:
                return f"holds an infinite {key}"
    return ""


def laws_problem(path: Path, task: NamedTask, contenders: list[str]) -> str:
    """Why ``<task>/laws.json`` must be scored again ("" to keep it): unreadable, recorded for another
    request (:func:`record_problem`; other ``contenders``), or a contender without a reason or whole scores."""
    record, why = read_result(path)
    if record is None:
        return why
    problem = record_problem(record, task, {"contenders": contenders})
    if problem:
        return problem
    scores = record.get("scores")
    if not isinstance(scores, dict) or set(scores) != set(contenders):
        return "holds no scores for every contender"
    for name, entry in scores.items():
        if isinstance(entry, dict) and isinstance(entry.get("note"), str):
            continue  # refused on this task: the reason
        problem = scores_problem(entry, len(task.eval_seeds))
        if problem:
            return f"{problem} for {name}"
    return ""


def run_problem(path: Path, task: NamedTask, algorithm: str, seed: int) -> str:
    """Why the training run at ``path`` cannot be kept ("" when it can): see :func:`laws_problem`."""
    record, why = read_result(path)
    if record is None:
        return why
    expected = {"algorithm": algorithm, "seed": seed}
    frames = record.get("frames")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        return "records no frame budget"
    return (
        record_problem(record, task, expected)
        or scores_problem(record, len(task.eval_seeds))
        or curve_problem(record, len(task.eval_seeds))
    )


def curve_problem(record: dict[str, Any], episodes: int) -> str:
    """Why a training run's learning curve and cost are not whole ("" when they are): ``curve`` a list of points
    (``frames`` from 0 up, whole scores each, the last the run's own), ``seconds`` and ``frames_per_second``."""
    curve = record.get("curve")
    if not isinstance(curve, list) or not curve or not all(isinstance(point, dict) for point in curve):
        return "records no learning curve (written by an older fxc leaderboard)"
    frames = [point.get("frames") for point in curve]
    if frames[0] != 0 or not all(isinstance(f, int) and not isinstance(f, bool) for f in frames):
        return "holds a learning curve that does not start at 0 frames"
    if frames != sorted(frames) or curve[-1]["frames"] != record["frames"]:
        return f"holds a learning curve whose frames {short_repr(frames)} do not rise to its {record['frames']}"
    for point in curve:
        if problem := scores_problem(point, episodes):
            return f"{problem} at {point['frames']} frames of its learning curve"
    if curve[-1]["deadline_error"] != record["deadline_error"]:
        return "holds scores other than its learning curve's last"
    seconds = record.get("seconds")
    if (
        not isinstance(seconds, dict)
        or set(seconds) != set(TIMERS)
        or not all(isinstance(v, int | float) and not isinstance(v, bool) and v >= 0 for v in seconds.values())
    ):
        return f"records no seconds {TIMERS}"
    rate = record.get("frames_per_second")
    if isinstance(rate, bool) or not isinstance(rate, int | float) or not rate > 0:
        return "records no frames_per_second"
    return ""


def result_commits(out: Path, tasks: list[NamedTask], algorithms: list[str], seeds: int) -> list[str]:
    """The fxc_env commits the table's result files under ``out`` record (a kept run may predate the table)."""
    paths = [out / task.id / "laws.json" for task in tasks]
    paths += [out / task.id / name / f"seed{k}.json" for task in tasks for name in algorithms for k in range(seeds)]
    return sorted({str(json.loads(path.read_text())["fxc_env_commit"]) for path in paths})


def versions() -> dict[str, str]:
    """What made the table: Python, the libraries that train and score, and fxc_env's git commit where it has one
    (``git describe --dirty``: a ``-dirty`` suffix when tracked files differ from it)."""
    return dict(_versions())


@functools.cache
def _versions() -> tuple[tuple[str, str], ...]:
    from importlib import metadata

    found = {"python": sys.version.split()[0]}
    for name in ("fxc_env", "numpy", "torch", "torchrl", "tensordict", "benchmarl", "torch_geometric"):
        try:
            found[name] = metadata.version(name.replace("_", "-") if name == "fxc_env" else name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    try:
        root = Path(__file__).resolve().parents[1]
        commit = subprocess.run(
            ["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=40"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        found["fxc_env_commit"] = commit.stdout.strip() if commit.returncode == 0 else "not a git checkout"
    except (OSError, subprocess.TimeoutExpired):
        found["fxc_env_commit"] = "git not found"
    return tuple(found.items())


def marl_eval_record(
    scores: dict[str, dict[str, np.ndarray]], energies: dict[str, dict[str, np.ndarray]], tasks: list[str], runs: int
) -> dict[str, Any]:
    """marl-eval's layout: env -> task -> algorithm -> seed_<k> -> step_0 / absolute_metrics.

    ``scores`` and ``energies``: per contender and task id, the (runs, episodes) arrays of the table. marl-eval
    needs every algorithm in every task, each with the same runs: only the contenders that scored every one of
    ``tasks`` are listed, and a law or shipped policy (one deterministic row of scores) is listed under each of
    the ``runs`` run keys of the trained algorithms (``seed_0`` .. ``seed_<runs-1>``) with the same scores.
    """
    out: dict[str, Any] = {task: {} for task in tasks}
    for name, by_task in scores.items():
        if not set(tasks) <= set(by_task):
            continue  # refused on some task: in table.md and laws.json only
        for task in tasks:
            errors, energy = by_task[task], energies[name][task]
            for k in range(runs):
                row = k if len(errors) == runs else 0  # a deterministic contender's one row under every run key
                out[task].setdefault(name, {})[f"seed_{k}"] = marl_eval_entry(errors[row], energy[row], 0)
    return {MARL_EVAL_ENV: out}


def profile_figure(scores: dict[str, dict[str, np.ndarray]], trained: tuple[str, ...], path: Path) -> None:
    """The performance profile: per contender, the fraction of its episodes with log10 D(T_s)/D(0) <= tau
    (``trained``: the BenchMARL algorithms, dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    taus = np.linspace(math.log10(LOG_FLOOR), 1.0, 200)
    figure, axes = plt.subplots(figsize=(9.5, 4.5))
    colours = plt.get_cmap("tab20")  # its 10 dark hues first, then their light twins: neighbours differ in hue
    for i, (name, by_task) in enumerate(scores.items()):
        decades = np.concatenate([statistics.decades(errors, LOG_FLOOR).ravel() for errors in by_task.values()])
        style = "--" if name in trained else "-"  # BenchMARL's algorithms dashed, laws and shipped policies solid
        fraction = [(decades <= tau).mean() for tau in taus]
        axes.step(taus, fraction, style, where="post", label=name, color=colours(2 * i % 20 + i // 10 % 2))
    axes.set_xlabel("tau: log10 D(T_s)/D(0)")
    axes.set_ylabel("fraction of episodes with log10 D(T_s)/D(0) <= tau")
    axes.set_ylim(0, 1.02)
    axes.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)  # beside the axes
    figure.tight_layout()
    figure.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(figure)


def write_json(path: Path, record: dict[str, Any]) -> None:
    """Write ``record`` whole or not at all (a rename), so an interrupted run leaves no half file to resume from."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".json.partial")
    partial.write_text(json.dumps(record, indent=1) + "\n")
    os.replace(partial, path)


def cost_lines(runs: dict[str, dict[str, list[dict[str, Any]]]]) -> list[str]:
    """The training-cost table's markdown lines: per task and algorithm, the medians over its training seeds of the
    frames, the seconds collecting and updating, the share of those in updates and the frames per second."""
    lines = [
        "Training cost (median over training seeds; seconds of one run; frames per second = frames / "
        "(collection + update); scoring the learning curve is not counted):",
        "",
        "| task | algorithm | frames | collection s | update s | update share | frames/s | wall s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for task_id, by_algorithm in runs.items():
        for algorithm, records in by_algorithm.items():
            seconds = {key: float(np.median([r["seconds"][key] for r in records])) for key in TIMERS}
            share = np.median([r["seconds"]["update"] / max(r["seconds"]["collection"] + r["seconds"]["update"], 1e-9)
                               for r in records])  # fmt: skip
            rate = float(np.median([r["frames_per_second"] for r in records]))
            frames = int(np.median([r["frames"] for r in records]))
            lines.append(f"| {task_id} | {algorithm} | {frames} | {seconds['collection']:.1f} | "
                         f"{seconds['update']:.1f} | {share:.0%} | {rate:.0f} | {seconds['wall']:.1f} |")  # fmt: skip
    return lines


def curve_figure(
    task_id: str, runs: dict[str, list[dict[str, Any]]], baselines: dict[str, np.ndarray], path: Path
) -> None:
    """One task's learning curves: frames against the deterministic actor's median D(T_s)/D(0) over the evaluation
    seeds, per algorithm the median over its training seeds (line) and their range (band); ``baselines``
    (name -> scores, e.g. the zero action and the reference) as horizontal lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(7.5, 4.5))
    colours = plt.get_cmap("tab10")
    for i, (algorithm, records) in enumerate(runs.items()):
        frames = [point["frames"] for point in records[0]["curve"]]
        medians = np.array([[np.median(point["deadline_error"]) for point in r["curve"]] for r in records])
        if any(len(row) != len(frames) for row in medians):
            continue  # seeds evaluated at other frames: not drawn as one band
        axes.plot(frames, np.median(medians, axis=0), "o-", color=colours(i), label=algorithm, markersize=3)
        axes.fill_between(frames, medians.min(axis=0), medians.max(axis=0), color=colours(i), alpha=0.2)
    for j, (name, errors) in enumerate(baselines.items()):
        level = float(np.median(errors))
        axes.axhline(level, color="k", linestyle=("--", ":", "-.")[j % 3], label=f"{name} ({level:.3g})")
    axes.set_yscale("log")
    starts = [
        record["curve"][1]["frames"] for records in runs.values() for record in records if len(record["curve"]) > 1
    ]
    if starts and max(r[0]["frames"] for r in runs.values()) > 4 * min(r[0]["frames"] for r in runs.values()):
        axes.set_xscale("symlog", linthresh=min(starts))  # budgets that differ (on- and off-policy): all legible
        axes.set_xlim(0, 1.1 * max(r[0]["frames"] for r in runs.values()))
    levels = [float(np.median(errors)) for errors in baselines.values()]
    low, high = axes.get_ylim()
    axes.set_ylim(min([low, *(level / 3 for level in levels if level > 0)]), max([high, *levels]))
    axes.set_xlabel("frames (environment steps of all agents)")
    axes.set_ylabel("median D(T_s)/D(0), deterministic actor")
    axes.set_title(f"{task_id}: median and range over training seeds")
    axes.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
