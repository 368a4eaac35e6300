"""The scores of several training seeds (:mod:`fxc_env.training.evaluation.seed_evaluation`) and the files they go to.

``seeds.md`` (the table), ``seeds.json`` (every estimate and interval, the runs and their seeds) and
``marl_eval.json``, the raw scores in the layout marl-eval reads (Gorsane et al. 2022)::

    {"fxc_env": {"<case>": {"<label>": {"seed_<k>": {
        "step_0": {"step_count": <timesteps trained>, "deadline_error": [S floats], ...},
        "absolute_metrics": {"deadline_error": [S floats], ...}}}}}}

a task per case, an algorithm per policy, a run per training seed (the reference, which has none, listed
under each run's key with the same scores), one value per initial state. Metrics: ``deadline_error``
(``D(T_s)/D(0)``), ``decades_reached`` (``-log10(max(D(T_s)/D(0), 1e-12))``, higher is better) and
``energy`` (``Σ_i ∫ u_i² dt``, m²/s³).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.baselines.harness.report import number_text
from fxc_env.baselines.harness.suite import Contender, Suite
from fxc_env.training.evaluation import statistics


@dataclass(frozen=True)
class TrainedRun:
    """One training seed of a policy.

    Attributes:
        entry: the path (or shipped name) it was found as.
        spec: what the benchmark loads (``model.zip`` inside an SB3 run directory; a torch or
            RLlib run directory itself; a file; a shipped name).
        seed: its training seed.
        timesteps: the agent-steps it was trained for (0 when nothing records them).
        trainer: how it was trained, as its run's ``config.json`` records it (``--backend diff --algo apg``);
            None when nothing records it (a bare policy file, a shipped policy).
    """

    entry: str
    spec: str
    seed: int
    timesteps: int
    trainer: str | None = None


#: Floor of the log column (the benchmark's ``log10(max(error, 1e-12))``).
LOG_FLOOR = 1e-12


#: The environment's name in ``marl_eval.json``.
MARL_EVAL_ENV = "fxc_env"


@dataclass(frozen=True)
class CaseScores:
    """The deadline errors and energies of one case: the runs' ``(R, S)`` and the reference's ``(S,)``.

    ``learned`` is None when a run could not play the case (``note`` says why).
    """

    case: Any
    seeds: tuple[int, ...]
    learned_error: np.ndarray | None
    learned_energy: np.ndarray | None
    reference_error: np.ndarray | None
    reference_energy: np.ndarray | None
    note: str = ""


def case_scores(
    results: Sequence[Any], suite: Suite, contenders: Sequence[Contender], runs: Sequence[TrainedRun]
) -> list[CaseScores]:
    """Per case of ``suite``, the scores at the headline budget (see :class:`CaseScores`)."""
    k = suite.headline_budget
    chosen = {
        (r.job.contender.name, r.job.case): r for r in results if r.job.n_intervals == k or not r.job.contender.sampled
    }
    out = []
    for case in suite.cases:
        reference = chosen.get(("reference", case))
        ref_ok = reference is not None and reference.error is None
        own = [chosen.get((c.name, case)) for c in contenders]
        refused = [r for r in own if r is None or r.error is not None]
        note = ""
        if refused:
            first = refused[0]
            note = "not run" if first is None else first.error
        out.append(
            CaseScores(
                case,
                tuple(run.seed for run in runs),
                None if refused else np.stack([r.metrics["relative_deadline_error"] for r in own]),
                None if refused else np.stack([r.metrics["energy"] for r in own]),
                reference.metrics["relative_deadline_error"] if ref_ok else None,
                reference.metrics["energy"] if ref_ok else None,
                note,
            )
        )
    return out


def intervals(scores: CaseScores, *, reps: int, seed: int) -> dict[str, Any]:
    """The median and IQM (decades) of the runs and of the reference, with their 95 % intervals."""

    def both(errors: np.ndarray) -> dict[str, Any]:
        return {
            "median_deadline_error": statistics.stratified_bootstrap(errors, "median", reps=reps, seed=seed).as_dict(),
            "iqm_log10_deadline_error": statistics.stratified_bootstrap(
                statistics.decades(errors, LOG_FLOOR), "iqm", reps=reps, seed=seed
            ).as_dict(),
        }

    record: dict[str, Any] = {"case": scores.case.key, "note": scores.note}
    if scores.learned_error is not None:
        record["learned"] = both(scores.learned_error)
        record["learned"]["per_seed_median_deadline_error"] = {
            str(s): float(np.median(row)) for s, row in zip(scores.seeds, scores.learned_error, strict=True)
        }
    if scores.reference_error is not None:
        record["reference"] = both(scores.reference_error[None, :])
    return record


def _cell(interval: dict[str, Any] | None, log: bool = False) -> str:
    if interval is None:
        return "—"
    show = (lambda v: "∞" if math.isinf(v) else f"{v:.2f}") if log else number_text
    return f"{show(interval['estimate'])} [{show(interval['low'])}, {show(interval['high'])}]"


def seed_table(records: Sequence[dict[str, Any]], label: str, seeds: Sequence[int]) -> str:
    """The markdown table of :func:`intervals` records, one row a case."""
    seed_text = ", ".join(str(s) for s in seeds)
    header = [
        "case",
        "reference: median D(T_s)/D(0) [95% CI]",
        f"{label}: median [95% CI]",
        "reference: IQM log10 [95% CI]",
        f"{label}: IQM log10 [95% CI]",
        f"{label}: median per seed ({seed_text})",
    ]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for record in records:
        learned, reference = record.get("learned"), record.get("reference")
        per_seed = (
            " / ".join(number_text(v) for v in learned["per_seed_median_deadline_error"].values())
            if learned
            else ("— (refused: see seeds.json)" if record["note"] else "—")
        )
        row = [
            record["case"],
            _cell(reference and reference["median_deadline_error"]),
            _cell(learned and learned["median_deadline_error"]),
            _cell(reference and reference["iqm_log10_deadline_error"], log=True),
            _cell(learned and learned["iqm_log10_deadline_error"], log=True),
            per_seed,
        ]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def marl_eval_entry(errors: np.ndarray, energies: np.ndarray, step_count: int) -> dict[str, Any]:
    """One run's entry in marl-eval's layout: ``step_0`` (with ``step_count``) and ``absolute_metrics``, each the
    episodes' ``deadline_error``, ``decades_reached`` and ``energy`` lists."""
    metrics = {
        "deadline_error": [float(e) for e in errors],
        "decades_reached": [float(-d) for d in statistics.decades(errors, LOG_FLOOR)],
        "energy": [float(e) for e in energies],
    }
    return {"step_0": {"step_count": step_count, **metrics}, "absolute_metrics": metrics}


def marl_eval_record(scores: Sequence[CaseScores], runs: Sequence[TrainedRun], label: str) -> dict[str, Any]:
    """The raw scores in marl-eval's layout (see the module): env → case → algorithm → seed_<k> → step_0 / absolute_metrics.

    Cases a run could not play are left out (marl-eval needs every algorithm and run in every task); an
    ``inf`` (a diverged episode) is written as JSON's ``Infinity``.
    """
    tasks: dict[str, Any] = {}
    for case in scores:
        if case.learned_error is None or case.reference_error is None:
            continue
        algorithms: dict[str, Any] = {label: {}, "reference": {}}
        for i, run in enumerate(runs):
            seed = f"seed_{run.seed}"
            algorithms[label][seed] = marl_eval_entry(case.learned_error[i], case.learned_energy[i], run.timesteps)
            algorithms["reference"][seed] = marl_eval_entry(case.reference_error, case.reference_energy, run.timesteps)
        tasks[case.case.key] = algorithms
    return {MARL_EVAL_ENV: tasks}


def write_seed_report(
    out: Path,
    scores: Sequence[CaseScores],
    runs: Sequence[TrainedRun],
    label: str,
    *,
    reps: int,
    seed: int,
    command: str | None = None,
) -> tuple[str, list[Path]]:
    """Write ``seeds.md``, ``seeds.json`` and ``marl_eval.json`` into ``out``; returns the table and the files."""
    records = [intervals(s, reps=reps, seed=seed) for s in scores]
    table = seed_table(records, label, [run.seed for run in runs])
    budget = sorted({run.timesteps for run in runs})
    trained = (
        f"trained for {', '.join(str(b) for b in budget)} agent-steps"
        if 0 not in budget
        else "training budget not recorded in every run (0 in marl_eval.json's step_count)"
    )
    lines = [
        f"# {label}: {len(runs)} training seeds ({', '.join(str(r.seed) for r in runs)})",
        "",
        f"Runs: {', '.join(r.entry for r in runs)}; {trained}.",
        f"Median of D(T_s)/D(0) and IQM of log10(max(D(T_s)/D(0), {LOG_FLOOR:g})) over every training seed and "
        "initial state; 95% percentile intervals of a stratified bootstrap (training seeds resampled, then initial "
        f"states within each; {reps} replicates, bootstrap seed {seed}). The reference is one law: its interval "
        "resamples initial states only.",
    ]
    if command:
        lines += ["", f"Command: `{command}`"]
    markdown = "\n".join([*lines, "", table]) + "\n"
    summary = {
        "label": label,
        "runs": [{"entry": r.entry, "spec": r.spec, "seed": r.seed, "timesteps": r.timesteps} for r in runs],
        "bootstrap": {"reps": reps, "seed": seed, "confidence": 0.95, "log_floor": LOG_FLOOR},
        "command": command,
        "cases": records,
    }
    files = [out / "seeds.md", out / "seeds.json", out / "marl_eval.json"]
    files[0].write_text(markdown)
    files[1].write_text(json.dumps(summary, indent=2) + "\n")
    files[2].write_text(json.dumps(marl_eval_record(scores, runs, label), indent=2) + "\n")
    return table, files
