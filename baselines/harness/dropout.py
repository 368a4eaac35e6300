"""What a lost link costs the laws that claim exactness: ``fxc benchmark --suite dropout``.

Every law that claims exact consensus refuses ``link_dropout`` by name; its ``lossy`` opt-in
(:data:`~fxc_env.baselines.registry.LAWS`, ``allow_dropout=True``) runs it anyway. The dropout suite runs those
opt-ins and the reference on a directed ring and a random digraph of 20 at each of :data:`DROPOUT_LEVELS`, and
reports the deadline error's median, worst seed and share of exact seeds per law and level (docs: optimality.md,
"Lost links").
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fxc_env.analysis.plots import new_figure
from fxc_env.baselines.harness.figures import DISPLAY_FLOOR, optimality_style
from fxc_env.baselines.harness.report import EXACT_THRESHOLD, _table, exact_share, number_text, quantiles
from fxc_env.baselines.harness.suite import BenchmarkCase, Contender, Suite, builtin_contenders, optimality_variants
from fxc_env.baselines.registry import LAWS

if TYPE_CHECKING:
    from fxc_env.baselines.harness.jobs import JobResult

#: Probabilities that a link is lost on an interval (``link_dropout``), one case per level and graph.
DROPOUT_LEVELS = (1e-4, 1e-3, 1e-2, 1e-1)

#: The graphs of the dropout suite: a directed ring (slow mixing) and a random digraph (fast), N = 20.
DROPOUT_GRAPHS = (BenchmarkCase("ring", 20), BenchmarkCase("random", 20))


def dropout_cases() -> tuple[BenchmarkCase, ...]:
    """Each of :data:`DROPOUT_GRAPHS` at each of :data:`DROPOUT_LEVELS`."""
    return tuple(
        BenchmarkCase(g.topology, g.n_agents, conditions=(("link_dropout", p),))
        for g in DROPOUT_GRAPHS
        for p in DROPOUT_LEVELS
    )


def dropout_suite(n_seeds: int = 20, fine_intervals: int = 1000) -> Suite:
    """:func:`dropout_cases` at K = 200, T_s = 20 s; run it with :func:`dropout_contenders`."""
    cases = dropout_cases()
    return Suite(
        cases=cases,
        seeds=tuple(range(n_seeds)),
        budgets=(200,),
        fine_intervals=fine_intervals,
        trace_case=cases[1],  # the ring at p = 1e-3
        name="dropout",
    )


def quick_dropout_suite(n_seeds: int = 5, fine_intervals: int = 1000) -> Suite:
    """:func:`dropout_suite` on the ring only: seconds."""
    return replace(
        dropout_suite(n_seeds, fine_intervals), cases=dropout_cases()[: len(DROPOUT_LEVELS)], name="dropout-quick"
    )


def dropout_contenders() -> list[Contender]:
    """The reference (it takes lost links as they come), then every law's ``link_dropout`` opt-in."""
    lossy = [
        Contender(name, spec, law.sampled, schedule, law.action_mode, law.obs_mode)
        for law in LAWS.values()
        for name, spec, schedule in optimality_variants(law, dropout=True)
    ]
    return [*builtin_contenders(["reference"]), *lossy]


def _by_level(results: list[JobResult], contender: Contender, graph: BenchmarkCase) -> dict[float, np.ndarray]:
    """``{p: D(T_s)/D(0) per seed}`` of ``contender`` on ``graph``'s cases."""
    curve = {}
    for r in results:
        case = r.job.case
        if r.error is None and r.job.contender.name == contender.name and case.family == graph.family:
            curve[dict(case.conditions)["link_dropout"]] = np.asarray(r.metrics["relative_deadline_error"], float)
    return dict(sorted(curve.items()))


def dropout_table(results: list[JobResult], contenders: list[Contender]) -> str:
    """Per graph and law, per level: ``median / worst · exact share`` of D(T_s)/D(0) over seeds."""
    header = ["graph", "policy", *(f"p = {p:g}" for p in DROPOUT_LEVELS)]
    rows = []
    for graph in DROPOUT_GRAPHS:
        for contender in contenders:
            curve = _by_level(results, contender, graph)
            if not curve:
                continue
            cells = []
            for p in DROPOUT_LEVELS:
                errors = curve.get(p)
                if errors is None:
                    cells.append("—")
                    continue
                worst = float(np.max(errors)) if errors.size else float("nan")
                cells.append(f"{number_text(quantiles(errors)[0])} / {number_text(worst)} · {exact_share(errors):.0%}")
            rows.append([graph.key, contender.name, *cells])
    return _table(header, rows)


def dropout_section(results: list[JobResult], contenders: list[Contender]) -> str:
    """The report's section: the table and what its cells hold."""
    return "\n".join(
        [
            "### Lost links: D(T_s)/D(0) median / worst over seeds · share of exact seeds, against link_dropout p",
            "",
            dropout_table(results, contenders),
            "",
            f"Exact: D(T_s)/D(0) ≤ {EXACT_THRESHOLD:g}. `<law>/lossy` is the law run with allow_dropout=True: every "
            "law that claims exactness refuses link_dropout without it, and its guarantee() says what a lost link "
            "costs. The reference runs under lost links as it is.",
        ]
    )


def dropout_figure(results: list[JobResult], contenders: list[Contender], path: Path) -> Path:
    """Two panels (ring, random digraph): D(T_s)/D(0) against p, median (solid) and worst seed (dashed) per law."""
    fig = new_figure(11.0, 4.4)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, graph in zip(axes, DROPOUT_GRAPHS, strict=True):
        for contender in contenders:
            curve = _by_level(results, contender, graph)
            if not curve:
                continue
            marker, colour = optimality_style(contenders, contender.name)
            levels = list(curve)
            median = [max(quantiles(e)[0], DISPLAY_FLOOR) for e in curve.values()]
            worst = [min(max(float(np.max(e)), DISPLAY_FLOOR), 1e12) for e in curve.values()]
            ax.plot(levels, median, "-", marker=marker, color=colour, mfc="none", label=contender.name)
            ax.plot(levels, worst, "--", color=colour, lw=0.8, alpha=0.7)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        ax.axhline(EXACT_THRESHOLD, color="black", lw=0.8, ls=":")
        ax.set_xlabel("link_dropout p (probability a link is lost on an interval)")
        ax.set_title(f"{graph.key}, K = 200 uniform\nsolid: median over seeds; dashed: worst seed", fontsize=9)
    axes[0].set_ylabel(f"D(T_s)/D(0) (exact ≤ {EXACT_THRESHOLD:g}, dotted; 0 drawn at {DISPLAY_FLOOR:g})")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="center left", bbox_to_anchor=(0.8, 0.5), fontsize=7)
    fig.tight_layout(rect=(0.0, 0.0, 0.8, 1.0))
    fig.savefig(path)
    return path
