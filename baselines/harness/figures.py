"""The benchmark's figures, written headless as PNG (matplotlib's Agg canvas, as :mod:`fxc_env.analysis.plots`):
``deadline_vs_budget.png``, ``energy_vs_error.png``, ``disagreement_vs_time.png`` and, for the optimality suite,
``error_vs_energy_ratio.png`` (:func:`optimality_figure`) (docs: benchmark.md, "Baselines and the deadline benchmark").
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fxc_env.analysis.plots import new_figure, save_figure
from fxc_env.baselines.harness.report import quantiles

if TYPE_CHECKING:
    from fxc_env.baselines.harness.jobs import JobResult
    from fxc_env.baselines.harness.suite import Contender, Suite

#: Values below this (exact agreement, round-off) are drawn at it on log axes.
DISPLAY_FLOOR = 1e-18
COLOURS = (
    "#1f77b4",
    "#d62728",
    "#2ca02c",
    "#9467bd",
    "#ff7f0e",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#bcbd22",
    "#7f7f7f",
    "#000000",
    "#aec7e8",
    "#ff9896",
    "#98df8a",
    "#c5b0d5",
    "#c49c94",
    "#f7b6d2",
    "#dbdb8d",
    "#393b79",
)
#: One marker per policy where points of several policies may coincide (the optimality figure). The first
#: contenders take these pairs in turn; later ones a numbered marker and a colour of their own (:func:`style_at`),
#: so a newly registered law is drawn distinctly without an entry here.
MARKERS = (
    "o",
    "^",
    "v",
    "D",
    "s",
    "P",
    "X",
    "*",
    "<",
    ">",
    "h",
    "p",
    "d",
    "8",
    "H",
    "$\\triangle$",
    "$\\diamond$",
    "$\\star$",
    "$\\odot$",
)


def style_at(index: int) -> tuple[str, str]:
    """``(marker, colour)`` of the ``index``-th contender (from 0): the pairs of :data:`MARKERS` and :data:`COLOURS`
    first, then the index as a mathtext marker with a hue stepped by the golden ratio (each pair its own)."""
    if index < min(len(MARKERS), len(COLOURS)):
        return MARKERS[index], COLOURS[index]
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    return f"${index}$", to_hex(colormaps["hsv"]((index * 0.6180339887) % 1.0))


def _colour(contenders: list[Contender], name: str) -> str:
    return optimality_style(contenders, name)[1]


def _visible(value: float) -> float:
    """Clamp a positive quantity to :data:`DISPLAY_FLOOR` for a log axis (inf and NaN become NaN)."""
    return max(value, DISPLAY_FLOOR) if np.isfinite(value) else np.nan


def _ran(results: list[JobResult], contender: Contender, keep: Any = None) -> list[JobResult]:
    """The results ``contender`` ran (no error), those ``keep`` accepts where given."""
    return [r for r in results if r.error is None and r.job.contender.name == contender.name and (not keep or keep(r))]


def _budget_panel(ax, results: list[JobResult], suite: Suite, contenders: list[Contender], case=None) -> None:
    for contender in contenders:
        mine = _ran(results, contender, lambda r: case in (None, r.job.case))
        budgets = sorted({r.job.n_intervals for r in mine})
        stats = []
        for k in budgets:
            pooled = np.concatenate([r.metrics["relative_deadline_error"] for r in mine if r.job.n_intervals == k])
            stats.append([_visible(q) for q in quantiles(pooled)])
        if not stats:
            continue
        median, low, high = np.array(stats).T
        colour = _colour(contenders, contender.name)
        if contender.sampled:
            ax.plot(budgets, median, "o-", color=colour, label=contender.name, ms=4)
            ax.fill_between(budgets, low, high, color=colour, alpha=0.15)
        else:
            ax.errorbar(budgets, median, yerr=[median - low, high - median], fmt="s", color=colour, ms=5, capsize=3)
            ax.plot([], [], "s", color=colour, label=f"{contender.name} (fine K, ZOH)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("communication budget K (sampling instants)")
    ax.set_ylabel("relative deadline error D(T_s)/D(0)")
    ax.grid(alpha=0.3, which="both")


def deadline_vs_budget_figure(results: list[JobResult], suite: Suite, contenders: list[Contender], path: Path) -> Path:
    """Deadline error against K: all cases pooled (left) and the trace case (right)."""
    fig = new_figure(12.0, 4.6)
    left, right = fig.subplots(1, 2)
    _budget_panel(left, results, suite, contenders)
    left.set_title(f"all cases pooled: median, band/bars = [q25, q75]; 0 drawn at {DISPLAY_FLOOR:g}", fontsize=9)
    _budget_panel(right, results, suite, contenders, suite.trace_case)
    assumed = " (assumed Fig. 1)" if suite.trace_case.topology == "paper_fig1" else ""
    right.set_title(f"{suite.trace_case.key}{assumed}", fontsize=9)
    right.legend(fontsize=7)
    return save_figure(fig, path)


def energy_vs_error_figure(results: list[JobResult], contenders: list[Contender], path: Path) -> Path:
    """Energy against deadline error, one point per (policy, case, K), medians over seeds."""
    fig = new_figure(7.5, 5.0)
    ax = fig.subplots()
    for contender in contenders:
        mine = _ran(results, contender)
        if not mine:
            continue
        error = [_visible(quantiles(r.metrics["relative_deadline_error"])[0]) for r in mine]
        energy = [_visible(quantiles(r.metrics["energy"])[0]) for r in mine]
        marker = "o" if contender.sampled else "s"
        ax.scatter(error, energy, s=14, marker=marker, color=_colour(contenders, contender.name), label=contender.name)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("relative deadline error D(T_s)/D(0) (median over seeds)")
    ax.set_ylabel("energy Σ_i ∫ u_i² dt (m²/s³, median over seeds)")
    ax.set_title(f"cost against accuracy: one point per policy, case and K; 0 drawn at {DISPLAY_FLOOR:g}", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return save_figure(fig, path)


def disagreement_figure(results: list[JobResult], suite: Suite, contenders: list[Contender], path: Path) -> Path:
    """Median ``D(t)/D(0)`` against t on the trace case, every policy (sampled ones at the headline K)."""
    fig = new_figure(8.0, 4.6)
    ax = fig.subplots()
    for contender in contenders:
        k = suite.headline_budget if contender.sampled else suite.fine_intervals
        match = _ran(
            results,
            contender,
            lambda r, k=k: r.trace is not None and r.job.n_intervals == k and r.job.case == suite.trace_case,
        )
        if not match:
            continue
        trace = np.where(np.isfinite(match[0].trace), np.maximum(match[0].trace, DISPLAY_FLOOR), np.nan)
        style = "-" if contender.sampled else "--"
        ax.semilogy(
            match[0].trace_times,
            trace,
            style,
            lw=1.2,
            color=_colour(contenders, contender.name),
            label=f"{contender.name} (K={k})",
        )
    ax.axvline(suite.settling_time, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("D(t_k)/D(0), median over seeds")
    ax.set_title(
        f"disagreement against time on {suite.trace_case.key}, {len(suite.seeds)} seeded initial states", fontsize=9
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return save_figure(fig, path)


def optimality_style(contenders: list[Contender], name: str) -> tuple[str, str]:
    """``(marker, colour)`` of a law in the optimality figure (:func:`style_at` of its place among ``contenders``):
    each contender its own marker and its own colour (the figure draws every registered law; see its test)."""
    return style_at([c.name for c in contenders].index(name))


def _condition(case, name: str) -> float | None:
    return dict(case.conditions).get(name)


def _sweep_panel(ax, results: list[JobResult], contenders: list[Contender], name: str) -> dict[str, list]:
    """Median error against one condition (``obs_noise`` or ``u_max``) on the directed ring of 20; the floors seen."""
    floors: dict[str, list] = {}  # by schedule and K (the noise floor depends on the instants)
    for contender in contenders:
        mine = _ran(results, contender, lambda r: r.job.case.family == "ring" and r.job.case.n_agents == 20)
        mine = [r for r in mine if _condition(r.job.case, name) is not None]
        if not mine:
            continue
        mine.sort(key=lambda r: _condition(r.job.case, name))
        values = [_condition(r.job.case, name) for r in mine]
        error = [_visible(quantiles(r.metrics["relative_deadline_error"])[0]) for r in mine]
        marker, colour = optimality_style(contenders, contender.name)
        ax.plot(values, error, "-", color=colour, lw=0.8, alpha=0.6)
        ax.scatter(values, error, s=28, marker=marker, facecolors="none", edgecolors=colour)
        floor = "noise_floor" if name == "obs_noise" else "input_floor"
        for r, value in zip(mine, values, strict=True):
            key = f"{contender.schedule}, K={r.job.n_intervals}"
            floors.setdefault(key, []).append((value, quantiles(r.metrics[floor])))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    return floors


def _energy_panel(energy_ax: Any, results: list[JobResult], contenders: list[Contender]) -> None:
    """Deadline error against energy / E* on the ideal cases, one point per law and case, and the line E*."""
    for contender in contenders:
        mine = _ran(results, contender, lambda r: not r.job.case.conditions)
        ratio = [_visible(quantiles(r.metrics["energy_ratio"])[0]) for r in mine]
        error = [_visible(quantiles(r.metrics["relative_deadline_error"])[0]) for r in mine]
        marker, colour = optimality_style(contenders, contender.name)
        energy_ax.scatter(
            ratio,
            error,
            s=28,
            marker=marker,
            facecolors="none",
            edgecolors=colour,
            label=contender.name if contender.sampled else f"{contender.name} (fine K)",
        )
    energy_ax.axvline(1.0, color="black", lw=1.0, ls="--", label="E* (least energy of exact consensus)")
    energy_ax.axvspan(1e-3, 1.0, color="grey", alpha=0.12)
    energy_ax.set_xscale("log")
    energy_ax.set_yscale("log")
    energy_ax.set_xlim(left=0.3)
    energy_ax.set_xlabel("energy / E* (median over seeds)")
    energy_ax.set_ylabel("relative deadline error D(T_s)/D(0) (median over seeds)")
    energy_ax.set_title(
        f"ideal agents: error against energy / E*\n(one point per law and case; 0 drawn at {DISPLAY_FLOOR:g})",
        fontsize=9,
    )
    energy_ax.grid(alpha=0.3, which="both")


def _legend_entries(axes: Any) -> tuple[list, list]:
    """Every labelled handle of ``axes``, each label once."""
    handles, labels = [], []
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            if label not in labels:
                handles.append(handle)
                labels.append(label)
    return handles, labels


def optimality_figure(results: list[JobResult], contenders: list[Contender], path: Path) -> Path:
    """Three panels, medians over seeds, one marker and colour per law, the legend outside the axes: error
    against energy / E* (ideal cases), against ``obs_noise`` with the noise floor and against ``u_max`` with
    the input floor (docs: optimality.md, "How far from optimal")."""
    fig = new_figure(17.0, 5.0)
    energy_ax, noise_ax, limit_ax = fig.subplots(1, 3)
    _energy_panel(energy_ax, results, contenders)
    styles = ("--", ":", "-.", (0, (5, 1, 1, 1, 1, 1)))
    for index, (key, points) in enumerate(sorted(_sweep_panel(noise_ax, results, contenders, "obs_noise").items())):
        points = sorted(dict(points).items())
        noise_ax.plot(
            [p for p, _ in points],
            [q[0] for _, q in points],
            linestyle=styles[index % len(styles)],
            color="black",
            lw=1.2,
            label=f"noise floor ({key})",
        )
    noise_ax.set_xlabel("measurement noise obs_noise σ (m, m/s)")
    noise_ax.set_ylabel("D(T_s)/D(0) (median over seeds)")
    noise_ax.set_title("ring N=20 under noise\n(below a floor: no controller, on average)", fontsize=9)

    floors = [q for points in _sweep_panel(limit_ax, results, contenders, "u_max").values() for _, q in points]
    if floors:
        median, low, high = floors[0]
        limit_ax.axvline(median, color="black", lw=1.2, ls="--", label=f"input floor (median {median:.2g} m/s²)")
        limit_ax.axvspan(low, high, color="grey", alpha=0.2)
    limit_ax.set_xlabel("input limit u_max (m/s²)")
    limit_ax.set_ylabel("D(T_s)/D(0) (median over seeds)")
    limit_ax.set_title("ring N=20 under an input limit\n(left of the floor: no controller is exact)", fontsize=9)

    handles, labels = _legend_entries((energy_ax, noise_ax, limit_ax))
    fig.legend(handles, labels, loc="center left", bbox_to_anchor=(0.83, 0.5), fontsize=7, frameon=False)
    fig.tight_layout(rect=(0.0, 0.0, 0.83, 1.0))
    fig.savefig(path)
    return path


def write_figures(results: list[JobResult], suite: Suite, contenders: list[Contender], out_dir: Path) -> list[Path]:
    """Write the three PNGs into ``out_dir`` (four for the optimality suite: :func:`optimality_figure`)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = [
        deadline_vs_budget_figure(results, suite, contenders, out_dir / "deadline_vs_budget.png"),
        energy_vs_error_figure(results, contenders, out_dir / "energy_vs_error.png"),
        disagreement_figure(results, suite, contenders, out_dir / "disagreement_vs_time.png"),
    ]
    if suite.name.startswith("optimality"):
        files.append(optimality_figure(results, contenders, out_dir / "error_vs_energy_ratio.png"))
    return files
