"""The benchmark's tables: medians with the interquartile range ``[q25, q75]`` over episodes, as Markdown and CSV.

The headline table pools every case's episodes per policy (sampled policies at the headline budget); the others
break the deadline error down by case and by budget; the notes give each policy's law, source, proven graph
class, parameters and settings.
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fxc_env.baselines.harness.resolution import resolution_section
from fxc_env.core.metrics import EpisodeMetrics

if TYPE_CHECKING:
    from fxc_env.baselines.harness.jobs import JobResult
    from fxc_env.baselines.harness.suite import Contender, Suite

#: Deadline error below which an episode counts as having met the deadline.
MET_THRESHOLD = 1e-6
#: Deadline error at or below which an episode counts as exact: the tables report the share of such seeds beside
#: the median, which alone hides a split (some seeds exact, others at 1e-2).
EXACT_THRESHOLD = 1e-9

#: (metric, column heading) of the headline table, in the order of EpisodeMetrics.
HEADLINE_COLUMNS = (
    ("relative_deadline_error", "D(T_s)/D(0)"),
    ("final_position_spread", "e_x(T_s) (m)"),
    ("final_velocity_spread", "e_v(T_s) (m/s)"),
    ("t_eps_1e_2", "t(1e-2) (s)"),
    ("t_eps_1e_6", "t(1e-6) (s)"),
    ("energy", "energy (m²/s³)"),
    ("peak_input", "peak abs(u) (m/s²)"),
    ("final_value_gap", "abs(x̄ - x*) (m)"),
)

#: Metrics summarised per row of the CSV.
CSV_METRICS = (*(f.name for f in EpisodeMetrics.__dataclass_fields__.values()), "final_value_gap")


def quantiles(values: np.ndarray) -> tuple[float, float, float]:
    """``(median, q25, q75)``; NaN entries (metric does not apply) are ignored, inf counts as large."""
    finite_or_inf = values[~np.isnan(values)]
    if finite_or_inf.size == 0:
        return math.nan, math.nan, math.nan
    q25, median, q75 = np.quantile(finite_or_inf, [0.25, 0.5, 0.75], method="lower")
    return float(median), float(q25), float(q75)


def exact_share(values: np.ndarray) -> float:
    """The share of episodes with D(T_s)/D(0) ≤ :data:`EXACT_THRESHOLD` (NaN entries ignored, inf not exact)."""
    known = np.asarray(values, dtype=float)
    known = known[~np.isnan(known)]
    return float(np.mean(known <= EXACT_THRESHOLD)) if known.size else math.nan


def share_text(values: np.ndarray) -> str:
    """:func:`exact_share` as a percentage (``n/a`` without episodes)."""
    share = exact_share(values)
    return "n/a" if math.isnan(share) else f"{share:.0%}"


def number_text(value: float) -> str:
    """A table figure: 3 significant digits, 2 below 1e-2 and from 1e4 on; ``n/a``, ``∞``, ``0``."""
    if math.isnan(value):
        return "n/a"
    if math.isinf(value):
        return "∞"
    if value == 0:
        return "0"
    return f"{value:.2g}" if abs(value) < 1e-2 or abs(value) >= 1e4 else f"{value:.3g}"


def spread_cell(values: np.ndarray) -> str:
    """``median [q25, q75]``."""
    median, q25, q75 = quantiles(values)
    return "n/a" if math.isnan(median) else f"{number_text(median)} [{number_text(q25)}, {number_text(q75)}]"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _ran(results: list[JobResult]) -> list[JobResult]:
    return [r for r in results if r.error is None]


def _pooled(results: list[JobResult], metric: str) -> np.ndarray:
    arrays = [r.metrics[metric] for r in results]
    return np.concatenate(arrays) if arrays else np.zeros(0)


def _headline_results(results: list[JobResult], suite: Suite, name: str) -> list[JobResult]:
    return [
        r
        for r in _ran(results)
        if r.job.contender.name == name and (r.job.n_intervals == suite.headline_budget or not r.job.contender.sampled)
    ]


def aggregate(results: list[JobResult]) -> list[dict[str, Any]]:
    """One CSV row per job: settings, guarantee, parameters, and median/q25/q75 of every metric."""
    rows = []
    for r in results:
        job = r.job
        row: dict[str, Any] = {
            "policy": job.contender.name,
            "case": job.case.key,
            "topology": job.case.family,
            "n_agents": job.case.n_agents,
            "n_intervals": job.n_intervals,
            "schedule": job.contender.schedule,
            "action_mode": job.contender.action_mode,
            "obs_mode": job.contender.obs_mode,
            "settling_time": job.settling_time,
            "n_episodes": len(job.seeds),
            "guarantee": r.guarantee,
            "parameters": "; ".join(f"{k}={v:.6g}" for k, v in r.parameters.items()),
            "error": r.error or "",
            "seconds": round(r.seconds, 3),
        }
        if r.error is None:
            relative = r.metrics["relative_deadline_error"]
            row["diverged"] = int(np.sum(~np.isfinite(relative)))
            row["met_1e-6"] = float(np.mean(relative <= MET_THRESHOLD))
            row["exact_1e-9"] = exact_share(relative)
            for metric in CSV_METRICS:
                median, q25, q75 = quantiles(np.asarray(r.metrics[metric], dtype=float))
                row[f"{metric}_median"], row[f"{metric}_q25"], row[f"{metric}_q75"] = median, q25, q75
        rows.append(row)
    return rows


def episode_rows(results: list[JobResult]) -> list[dict[str, Any]]:
    """One CSV row per episode (policy, case, K, seed and every metric)."""
    rows = []
    for r in _ran(results):
        for b, seed in enumerate(r.job.seeds):
            row = {
                "policy": r.job.contender.name,
                "case": r.job.case.key,
                "n_intervals": r.job.n_intervals,
                "seed": seed,
            }
            rows.append({**row, **{m: float(r.metrics[m][b]) for m in (*CSV_METRICS, "initial_disagreement")}})
    return rows


def write_csv(rows: list[dict[str, Any]], path: Path) -> Path:
    """Write dict rows (the union of their keys as columns) to ``path``."""
    columns = list(dict.fromkeys(key for row in rows for key in row))
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    return path


def write_text(text: str, path: Path) -> Path:
    path.write_text(text + "\n")
    return path


#: The column of the share of exact seeds (:func:`exact_share`).
EXACT_TITLE = f"exact ≤ {EXACT_THRESHOLD:g}"


def error_cell(values: np.ndarray) -> str:
    """``median [q25, q75] · share exact``: a deadline error's spread and the share of exact seeds."""
    return f"{spread_cell(values)} · {share_text(values)} exact"


def headline_table(results: list[JobResult], suite: Suite, contenders: list[Contender]) -> str:
    """Per policy, all cases pooled: the episode metrics as ``median [q25, q75]``."""
    header = ["policy", "K", *(title for _, title in HEADLINE_COLUMNS), f"met ≤ {MET_THRESHOLD:g}", EXACT_TITLE]
    rows = []
    for contender in contenders:
        chosen = _headline_results(results, suite, contender.name)
        if not chosen:
            continue
        k = suite.headline_budget if contender.sampled else suite.fine_intervals
        relative = _pooled(chosen, "relative_deadline_error")
        cells = [spread_cell(_pooled(chosen, metric)) for metric, _ in HEADLINE_COLUMNS]
        rows.append([contender.name, str(k), *cells, f"{np.mean(relative <= MET_THRESHOLD):.0%}", share_text(relative)])
    return _table(header, rows)


#: The last column of the per-case tables: the case's intervals bounds (docs: optimality.md, "How far from optimal").
BOUNDS_TITLE = "intervals bound: radius (any law) / all roots"


def bounds_cell(results: list[JobResult], case: Any) -> str:
    """``radius / all-roots`` of a case's graph (medians over its episodes: families draw per episode); n/a for random switching."""
    ran = [r for r in _ran(results) if r.job.case == case and "radius_bound" in r.metrics]
    if not ran:
        return "—"
    radius, all_roots = (number_text(quantiles(ran[0].metrics[m])[0]) for m in ("radius_bound", "all_roots_bound"))
    return f"{radius} / {all_roots}"


def case_table(results: list[JobResult], suite: Suite, contenders: list[Contender]) -> str:
    """Deadline error per case (rows) and policy (columns) at the headline budget, and the case's intervals bounds."""
    names = [c.name for c in contenders]
    conditions = any(case.conditions for case in suite.cases)
    header = ["case", *(["floor"] if conditions else []), *names, BOUNDS_TITLE]
    rows = []
    for case in suite.cases:
        row = [case.key, *([_case_floors(results, case)] if conditions else [])]
        for name in names:
            match = [r for r in _headline_results(results, suite, name) if r.job.case == case]
            row.append(error_cell(match[0].metrics["relative_deadline_error"]) if match else "—")
        rows.append([*row, bounds_cell(results, case)])
    return _table(header, rows)


def floor_text(metrics: dict[str, np.ndarray]) -> str:
    """The floors of one job's episodes (medians): ``noise ≥ …`` on D(T_s)/D(0), ``u_max ≥ …`` (m/s²), ``worst D/D(0) ≥ …``
    under ``obs_resolution``; ``—`` without any."""
    parts = []
    # the resolution floor: a worst case over the states that read all zeros (resolution.py)
    for metric, label in (("noise_floor", "D/D(0)"), ("input_floor", "u_max"), ("resolution_floor", "worst D/D(0)")):
        median = quantiles(np.asarray(metrics.get(metric, [np.nan]), dtype=float))[0]
        if not math.isnan(median):
            parts.append(f"{label} ≥ {number_text(median)}")
    return ", ".join(parts) or "—"


def _case_floors(results: list[JobResult], case: Any) -> str:
    """The floors of a case, per schedule where they differ (the noise floor depends on the instants)."""
    by_schedule: dict[str, str] = {}
    for r in _ran(results):
        if r.job.case == case:
            by_schedule.setdefault(r.job.contender.schedule, floor_text(r.metrics))
    texts = set(by_schedule.values())
    if len(texts) <= 1:
        return texts.pop() if texts else "—"
    return "; ".join(f"{text} ({schedule})" for schedule, text in by_schedule.items())


def realism_table(results: list[JobResult], suite: Suite, contenders: list[Contender]) -> str:
    """Per case and condition: the floors of any controller (:mod:`fxc_env.core.floors`), and each policy's
    median deadline error, saturated time share and energy."""
    names = [c.name for c in contenders]
    header = ["case", "condition", "floor", *names, BOUNDS_TITLE]
    rows = []
    for case in suite.cases:
        row = [f"{case.family} N={case.n_agents}", case.condition, _case_floors(results, case)]
        for name in names:
            match = [r for r in _headline_results(results, suite, name) if r.job.case == case]
            if not match:
                row.append("—")
                continue
            metrics = match[0].metrics
            error, saturated, energy = (
                quantiles(metrics[m])[0] for m in ("relative_deadline_error", "saturated_fraction", "energy")
            )
            exact = share_text(metrics["relative_deadline_error"])
            row.append(f"{number_text(error)} ({exact} exact) · sat {saturated:.0%} · E {number_text(energy)}")
        rows.append([*row, bounds_cell(results, case)])
    return _table(header, rows)


def optimality_table(results: list[JobResult], suite: Suite, contenders: list[Contender]) -> str:
    """Per case and policy: deadline error, energy / E*, intervals used against the radius and all-roots bounds."""
    header = [
        "case",
        "E* (m²/s³)",
        "policy",
        "K",
        "D(T_s)/D(0)",
        EXACT_TITLE,
        "energy / E*",
        "intervals used",
        "radius bound",
        "all-roots bound",
    ]
    conditions = any(case.conditions for case in suite.cases)
    if conditions:
        header.append("floor")
    rows = []
    for case in suite.cases:
        for contender in contenders:
            match = [r for r in _headline_results(results, suite, contender.name) if r.job.case == case]
            if not match:
                continue
            m = match[0].metrics
            settled = quantiles(m["settled_interval"])[0]
            rows.append(
                [
                    case.key,
                    number_text(quantiles(m["energy_bound"])[0]),
                    contender.name,
                    str(match[0].job.n_intervals),
                    spread_cell(m["relative_deadline_error"]),
                    share_text(m["relative_deadline_error"]),
                    spread_cell(m["energy_ratio"]),
                    "not by T_s" if math.isinf(settled) else f"{settled:.0f}",
                    number_text(quantiles(m["radius_bound"])[0]),
                    number_text(quantiles(m["all_roots_bound"])[0]),
                    *([floor_text(m)] if conditions else []),
                ]
            )
    return _table(header, rows)


def budget_table(results: list[JobResult], suite: Suite, contenders: list[Contender]) -> str:
    """Deadline error against the budget K, all cases pooled (continuous laws at their fine K)."""
    header = ["policy", *(f"K = {k}" for k in suite.budgets), f"K = {suite.fine_intervals} (fine)"]
    rows = []
    for contender in contenders:
        cells = []
        for k in (*suite.budgets, suite.fine_intervals):
            chosen = [r for r in _ran(results) if r.job.contender.name == contender.name and r.job.n_intervals == k]
            cells.append(spread_cell(_pooled(chosen, "relative_deadline_error")) if chosen else "—")
        rows.append([contender.name, *cells])
    return _table(header, rows)


def _parameter_ranges(chosen: list[JobResult]) -> str:
    names = list(dict.fromkeys(k for r in chosen for k in r.parameters))
    parts = []
    for name in names:
        values = np.array([r.parameters[name] for r in chosen if name in r.parameters])
        low, high = float(values.min()), float(values.max())
        parts.append(f"{name} = {number_text(low)}" + ("" if np.isclose(low, high) else f" … {number_text(high)}"))
    return ", ".join(parts)


def notes(results: list[JobResult], suite: Suite, contenders: list[Contender]) -> str:
    """Per policy: law, source, proven graph class, parameters, settings and guarantee counts."""
    lines = []
    for contender in contenders:
        mine = [r for r in results if r.job.contender.name == contender.name]
        ran = _ran(mine)
        budgets = suite.budgets if contender.sampled else (suite.fine_intervals,)
        settings = f"{contender.settings()}, K in {list(budgets)}"
        lines.append(f"- **{contender.name}** — settings: {settings}.")
        if ran and ran[0].description:
            d = ran[0].description
            lines.append(f"  Law: `{d['law']}`. Source: {d['source']}. Proven for: {d['graph_class']}.")
        elif contender.name.startswith("learned:"):
            from fxc_env.policies.learned import saved_format  # torch only when a learned policy is reported

            kind = saved_format(contender.spec)
            width = (
                "It reads any number of neighbour rows (a gain-scheduled network)."
                if contender.obs_slots is None
                else "Cases with more in-neighbours than its observation has rows are not run."
            )
            lines.append(
                f"  Law: a learned policy ({kind} `{contender.spec}`), one network shared by every agent; "
                f"no guarantee. {width}"
            )
        elif contender.spec == "reference":
            lines.append(
                "  Law: eq. (11), minimum-energy plan to the neighbourhood average of coasted states, paper "
                "schedule T_k = 6 T_s/(πk)², last interval closing at T_s. Proven for: digraphs with a "
                "directed spanning tree, fixed (Theorem 1) or periodically switching (Theorem 2)."
            )
        if ran and ran[0].parameters:
            lines.append(
                f"  Parameters (range over the suite; graph-dependent ones designed offline per graph and K): "
                f"{_parameter_ranges(ran)}."
            )
        verdicts = Counter(r.guarantee.split(" (")[0] for r in ran)
        if verdicts:
            lines.append("  Runs: " + "; ".join(f"{v} × {n}" for v, n in verdicts.items()) + ".")
        failed = [r for r in mine if r.error is not None]
        if failed:
            lines.append(f"  Not run on {len(failed)} job(s): {failed[0].error}")
    return "\n".join(lines)


def initial_state_text(suite: Suite) -> str:
    """The initial-state draw of the suite's cases: the default ranges, or the ranges a case's conditions set."""
    ranges = {name: value for case in suite.cases for name, value in case.conditions if name.endswith("_range")}
    position = ranges.get("position_range", 5.0)
    velocity = ranges.get("velocity_range", 2.0)

    def draw(value: Any, unit: str) -> str:
        if isinstance(value, tuple | list):  # LOW, HIGH: the half-width drawn log-uniformly per episode
            return f"U(-r, r) {unit}, r log-uniform in [{value[0]:g}, {value[1]:g}]"
        return f"U(-{value:g}, {value:g}) {unit}"

    return f"positions {draw(position, 'm')}, velocities {draw(velocity, 'm/s')}"


def _condition_sections(results: list[JobResult], suite: Suite, contenders: list[Contender]) -> list[str]:
    """The realism table where cases carry conditions; the optimality table for the optimality suites."""
    parts: list[str] = []
    if any(case.conditions for case in suite.cases):
        parts += [
            "### Realism: median deadline error D(T_s)/D(0) (share of exact seeds) · share of agent-time at the input limit · energy (m²/s³)",
            "",
            realism_table(results, suite, contenders),
            "",
            "Floor: what no controller, centralised or not, beats under the condition (medians over seeds): the "
            "least expected D(T_s)/D(0) under measurement noise, and the least u_max of exact consensus at T_s; "
            "under obs_resolution, the worst D(T_s)/D(0) of the states that read all zeros, which no law that "
            "applies no input on zero readings beats.",
            "",
        ]
    if suite.name.startswith("optimality"):
        parts += [
            "### How far from optimal: median [q25, q75] over seeds",
            "",
            optimality_table(results, suite, contenders),
            "",
            "E*: the least energy of any exact consensus at T_s from the episode's initial state (steer every "
            "agent once, minimum-energy, to the mean of the coasted states). Intervals used: median over seeds "
            "of the interval after which D(t_k)/D(0) stayed below 1e-9 ('not by T_s' when the median episode "
            "did not). Radius bound: the fewest intervals in which any law can be exact (the graph's radius: one "
            "agent's information must reach every agent). All-roots bound: the fewest after which every agent can "
            "have heard from every root, a bound only for laws whose value depends on every root (the paper's, "
            "the E*-optimal mean); n/a for random switching. ",
            "Floor (cases with noise or an input limit): D/D(0) ≥ the least expected error any controller leaves "
            "under the noise (least squares on every row the team receives); u_max ≥ the least input limit for "
            "which any controller reaches exact consensus (a linear programme).",
            "",
        ]
    return parts


def markdown_report(
    results: list[JobResult],
    suite: Suite,
    contenders: list[Contender],
    *,
    seconds: float | None = None,
    command: str | None = None,
) -> str:
    """The whole report: headline, per-case and per-budget tables, notes."""
    parts = ["## Deadline benchmark", "", suite.describe() + "."]
    if command:
        parts.append(f"Command: `{command}`" + (f" ({seconds:.0f} s wall time)." if seconds is not None else "."))
    parts += [
        "",
        f"### All cases pooled: median [q25, q75] over {len(suite.cases)} × {len(suite.seeds)} episodes",
        "",
        headline_table(results, suite, contenders),
        "",
        f"Sampled policies at K = {suite.headline_budget}, continuous laws at K = {suite.fine_intervals}. "
        "D = e_x + T_s e_v; t(eps) is the first instant after which D(t_k)/D(0) < eps (∞: not by T_s); "
        f"energy = Σ_i ∫ u_i² dt; abs(x̄ - x*) compares the achieved mean position with the reference's "
        "prediction ξᵀx(0) + T_s ξᵀv(0) (Theorems 1-2; other laws converge elsewhere on digraphs).",
        "",
        f"### Relative deadline error D(T_s)/D(0) by case: median [q25, q75] over seeds · share ≤ {EXACT_THRESHOLD:g}",
        "",
        case_table(results, suite, contenders),
        "",
    ]
    parts += _condition_sections(results, suite, contenders)
    parts += resolution_section(results)
    parts += [
        "### Relative deadline error against the communication budget K (all cases pooled)",
        "",
        budget_table(results, suite, contenders),
        "",
        "### Notes",
        "",
        notes(results, suite, contenders),
        "",
        "Every policy reads only its agent's observation (in-neighbour rows, mask, clock) and the "
        "environment's settings; gains chosen from the graph are an offline design, the same for "
        f"every agent. Initial states: {initial_state_text(suite)}, from "
        f"numpy.random.default_rng(seed), seeds {suite.seeds[0]}..{suite.seeds[-1]}, identical for every policy.",
    ]
    return "\n".join(parts)
