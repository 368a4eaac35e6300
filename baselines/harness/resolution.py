"""Deadline error against the measurement quantum ``obs_resolution``, beside the resolution floor.

The floor (:func:`fxc_env.core.floors.resolution_floor`) is the worst ``D(T_s)`` over the initial states
whose every reading is 0 at quantum ``q``: a law that applies no input while it reads only zeros lets
them coast (docs: optimality.md, "The floors, derived"). :func:`resolution_section` puts each case's floor,
its best law and the ratio in ``fxc benchmark``'s report; ``python -m fxc_env.baselines.harness.resolution`` runs
every registered law on :func:`resolution_suite`, prints that table and writes the frontier figure.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.baselines.harness.suite import BenchmarkCase, Suite

__all__ = [
    "FRONTIER_CASES",
    "RESOLUTIONS",
    "frontier_figure",
    "resolution_rows",
    "resolution_section",
    "resolution_suite",
    "with_resolution",
]

#: The quanta (m, m/s) of the frontier.
RESOLUTIONS = (1e-4, 1e-3, 1e-2, 1e-1)
#: The graphs of the frontier: a slow-mixing directed ring and a random digraph, N = 20.
FRONTIER_CASES = (BenchmarkCase("ring", 20), BenchmarkCase("random", 20))


def resolution_suite(n_seeds: int = 5, resolutions: Sequence[float] = RESOLUTIONS, fine_intervals: int = 1000) -> Suite:
    """:data:`FRONTIER_CASES` under each quantum of ``resolutions``, K = 200, T_s = 20 s, seeds ``0 .. n_seeds - 1``."""
    cases = tuple(
        BenchmarkCase(case.topology, case.n_agents, conditions=(("obs_resolution", float(q)),))
        for case in FRONTIER_CASES
        for q in resolutions
    )
    return Suite(cases, tuple(range(n_seeds)), (200,), fine_intervals, trace_case=cases[0], name="resolution")


def with_resolution(suite: Suite, quantum: Any) -> Suite:
    """``suite`` and, after its cases, each case without conditions again measured at ``quantum``.

    ``fxc benchmark --obs-resolution``: the tables then show each case with exact and with rounded rows,
    the latter with its resolution floor. None or 0: ``suite`` unchanged. ``quantum`` is checked where
    every front end's is (``obs_resolution``'s row of :data:`fxc_env.config.arguments.ARGUMENTS`): a bad
    value raises ArgumentError naming ``obs_resolution``.
    """
    from fxc_env.config.arguments import ARGUMENTS

    q = ARGUMENTS["obs_resolution"].check(quantum)
    if not q:
        return suite
    rounded = tuple(replace(case, conditions=(("obs_resolution", q),)) for case in suite.cases if not case.conditions)
    return replace(suite, cases=(*suite.cases, *rounded))


def _quantum(case: Any) -> float | None:
    return dict(case.conditions).get("obs_resolution")


def resolution_rows(results: list[Any]) -> list[dict[str, Any]]:
    """Per case with a resolution floor: the quantum, the floor and the best law's error (medians over seeds).

    ``ratio`` is the median over episodes of ``error / floor`` (both over the same ``D(0)``): at least 1
    on the floor's own worst state for every law; on the suite's random states a law may go below it
    (the floor is a worst case over a set, not a bound on each state).
    """
    rows = []
    for case in dict.fromkeys(r.job.case for r in results):
        ran = [r for r in results if r.job.case == case and r.error is None and r.metrics]
        floors = [r.metrics.get("resolution_floor") for r in ran]
        if not ran or floors[0] is None or not np.all(np.isfinite(floors[0])):
            continue
        best = min(ran, key=lambda r: float(np.median(r.metrics["relative_deadline_error"])))
        error, floor = best.metrics["relative_deadline_error"], best.metrics["resolution_floor"]
        rows.append(
            {
                "case": f"{case.family} N={case.n_agents}",
                "resolution": _quantum(case),
                "floor": float(np.median(floor)),
                "best": best.job.contender.name,
                "error": float(np.median(error)),
                "ratio": float(np.median(error / floor)),
            }
        )
    return rows


def resolution_section(results: list[Any]) -> list[str]:
    """Markdown lines of :func:`resolution_rows` (none where no case has a resolution floor)."""
    rows = resolution_rows(results)
    if not rows:
        return []
    lines = [
        "### Resolution floor: the best law against it (medians over seeds)",
        "",
        "| case | obs_resolution | floor D/D(0) | best law | its D(T_s)/D(0) | ratio |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['case']} | {row['resolution']:g} | {row['floor']:.3g} | {row['best']} | "
            f"{row['error']:.3g} | {row['ratio']:.3g} |"
        )
    lines += [
        "",
        "The floor is the worst D(T_s) over the initial states whose every reading is 0 at that quantum "
        "(a law that applies no input on zero readings lets them coast), over each episode's D(0): a worst "
        'case over a set, so one state may end below it (docs: optimality.md, "The floors, derived").',
        "",
    ]
    return lines


def frontier_figure(results: list[Any], path: Path | str) -> Path:
    """Median ``D(T_s)/D(0)`` of every law against ``obs_resolution``, one panel per graph, with the floor; a PNG."""
    from fxc_env.analysis.plots import new_figure

    families = list(dict.fromkeys((r.job.case.family, r.job.case.n_agents) for r in results))
    names = list(dict.fromkeys(r.job.contender.name for r in results))
    fig = new_figure(5.2 * len(families), 5.0)
    axes = fig.subplots(1, len(families), squeeze=False)[0]
    for ax, (family, n) in zip(axes, families, strict=True):
        mine = [r for r in results if (r.job.case.family, r.job.case.n_agents) == (family, n)]
        for index, name in enumerate(names):
            points = sorted(
                (_quantum(r.job.case), float(np.median(r.metrics["relative_deadline_error"])))
                for r in mine
                if r.job.contender.name == name and r.error is None and r.metrics
            )
            if points and all(math.isfinite(y) and y < 1e3 for _, y in points):
                ax.plot(*zip(*points, strict=True), marker="o", lw=1.2, color=f"C{index % 10}", label=name)
        floor = sorted(
            {(_quantum(r.job.case), float(np.median(r.metrics["resolution_floor"]))) for r in mine if r.metrics}
        )
        ax.plot(*zip(*floor, strict=True), "k--", lw=2.0, label="resolution floor (worst silent state)")
        ax.set(xscale="log", yscale="log", xlabel="obs_resolution q (m, m/s)", ylabel="D(T_s) / D(0), median")
        ax.set_title(f"{family} N={n}, K = 200, T_s = 20 s")
        ax.grid(True, which="major", alpha=0.3)
    handles = {label: line for ax in axes for line, label in zip(*ax.get_legend_handles_labels(), strict=True)}
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=5, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run every registered law on :func:`resolution_suite`; print the table; write the figure."""
    from fxc_env.baselines.harness.jobs import make_jobs, run_in_processes
    from fxc_env.baselines.harness.suite import builtin_contenders

    parser = argparse.ArgumentParser(prog="python -m fxc_env.baselines.harness.resolution", description=main.__doc__)
    parser.add_argument("--seeds", type=int, default=5, help="seeded initial states per case")
    parser.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    parser.add_argument("--out", default="out/resolution_frontier.png", help="the figure's path")
    args = parser.parse_args(argv)
    results = run_in_processes(make_jobs(resolution_suite(args.seeds), builtin_contenders()), args.workers)
    refused = sorted({(r.job.contender.name, r.error.split(":")[0]) for r in results if r.error})
    print("\n".join(resolution_section(results)))
    print("refused: " + ", ".join(f"{name} ({argument})" for name, argument in refused))
    print(f"wrote {frontier_figure([r for r in results if r.error is None], args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
