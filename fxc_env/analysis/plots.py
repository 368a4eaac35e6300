"""Figures of a whole run, written as PNG (the paper's Figs 1-3, inputs, disagreement)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from fxc_env.analysis.simulation import Trajectory
from fxc_env.core.graphs import Topology
from fxc_env.envs.rendering import agent_colours, draw_graph

#: Agents drawn individually; beyond this the curves carry no legend.
LEGEND_LIMIT = 12


def new_figure(width: float = 7.0, height: float = 4.2) -> Figure:
    """A headless (Agg) figure at 120 dpi."""
    fig = Figure(figsize=(width, height), dpi=120)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    """Lay out and write ``fig`` as PNG to ``path``."""
    fig.tight_layout()
    fig.savefig(path)
    return path


def _legend(ax) -> None:
    """A legend only where something is labelled (agents are labelled up to LEGEND_LIMIT)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, ncol=2)


def _component_note(trajectory: Trajectory) -> str:
    return " (first component)" if trajectory.config.dim > 1 else ""


def topology_figure(trajectory: Trajectory, path: Path) -> Path:
    """The graphs of the switching period and their union (the assumed Fig. 1 of docs: scenarios/paper_fig1.md)."""
    topology = trajectory.topology
    m = topology.period
    panels = m + 1 if m > 1 else 1
    fig = new_figure(2.6 * panels, 3.0)
    axes = np.atleast_1d(fig.subplots(1, panels))
    for g in range(m):
        title = f"G_{g}" if m > 1 else "G"
        draw_graph(axes[g], topology, g, title=title + f"  ({len(topology.edges[g])} edges)")
    if m > 1:
        union = Topology(topology.n_agents, (np.concatenate(topology.edges),))
        draw_graph(axes[m], union, 0, title="union of the period")
    heading = topology.name + (f": {topology.note}" if topology.note else "")
    fig.suptitle(heading + "\narrow j -> i: agent i receives from agent j (0-based)", fontsize=9)
    return save_figure(fig, path)


def _draw_state(ax, trajectory: Trajectory, which: str) -> None:
    c = trajectory.config
    dense = trajectory.dense_x if which == "x" else trajectory.dense_v
    sampled = trajectory.x if which == "x" else trajectory.v
    colours = agent_colours(c.n_agents)
    for i in range(c.n_agents):
        label = f"agent_{i}" if c.n_agents <= LEGEND_LIMIT else None
        ax.plot(trajectory.dense_times, dense[:, i, 0], color=colours[i], lw=1.2, label=label)
        ax.plot(trajectory.times, sampled[:, i, 0], ".", color=colours[i], ms=3)
    metrics = trajectory.metrics
    # The dashed line x*(t) = xi^T x(0) + t xi^T v(0) is the double integrator's (a general agent's
    # z*(t) = e^{A t} sum_j xi_j z_j(0) bends; with formation offsets each agent has its own target).
    plain = c.model is None and c.formation is None
    if plain and np.isfinite(metrics.predicted_final_velocity):
        # Theorems 1-2: x*(t) = xi^T x(0) + t xi^T v(0), v* = xi^T v(0).
        slope = metrics.predicted_final_velocity
        base = metrics.predicted_final_position - slope * c.settling_time
        final = base + slope * trajectory.dense_times if which == "x" else np.full_like(trajectory.dense_times, slope)
        ax.plot(trajectory.dense_times, final, "k--", lw=0.9, label="x*(t) from xi" if which == "x" else "v* from xi")
    ax.axvline(c.settling_time, color="grey", lw=0.8, ls=":")
    quantity = "position x_i(t)" if which == "x" else "velocity v_i(t)"
    unit = "m" if which == "x" else "m/s"
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"{quantity} ({unit}){_component_note(trajectory)}")
    model = "" if c.model is None else f"\nagents: {_model_label(c)}"
    ax.set_title(
        f"{quantity}: {trajectory.topology.name}, N={c.n_agents}, K={c.n_intervals}, T_s={c.settling_time:g} s "
        f"(dots: sampling instants){model}",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    _legend(ax)


def _model_label(config) -> str:
    """``integrator_chain (n = 3)``, ``damped``, ...: the agents' model for titles."""
    if config.agent_model == "integrator_chain":
        return f"integrator chain of order {config.n_states}"
    return config.agent_model.replace("_", " ")


def formation_figure(trajectory: Trajectory, path: Path) -> Path:
    """Paths in the plane (first two axes) from the start (circles) to the formation at ``T_s`` (squares, joined)."""
    c = trajectory.config
    fig = new_figure(6.0, 5.6)
    ax = fig.subplots()
    colours = agent_colours(c.n_agents)
    x = trajectory.dense_x
    for i in range(c.n_agents):
        label = f"agent_{i}" if c.n_agents <= LEGEND_LIMIT else None
        ax.plot(x[:, i, 0], x[:, i, 1], color=colours[i], lw=0.9, label=label)
        ax.plot(*trajectory.x[0, i, :2], "o", color=colours[i], ms=5, mfc="none")
    final = trajectory.x[-1, :, :2]
    ax.plot(*np.concatenate([final, final[:1]]).T, "k-", lw=0.8, alpha=0.6)
    ax.plot(*final.T, "ks", ms=5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x_i, first axis (m)")
    ax.set_ylabel("x_i, second axis (m)")
    error = trajectory.metrics.relative_deadline_error
    ax.set_title(
        f"formation at T_s = {c.settling_time:g} s (squares); formation error D(T_s)/D(0) = {error:.1e}", fontsize=9
    )
    ax.grid(alpha=0.3)
    _legend(ax)
    return save_figure(fig, path)


def _state_figure(trajectory: Trajectory, path: Path, which: str) -> Path:
    fig = new_figure()
    _draw_state(fig.subplots(), trajectory, which)
    return save_figure(fig, path)


def overview_figure(trajectory: Trajectory, path: Path) -> Path:
    """Positions and velocities side by side (the README's picture)."""
    fig = new_figure(12.0, 4.2)
    left, right = fig.subplots(1, 2)
    _draw_state(left, trajectory, "x")
    _draw_state(right, trajectory, "v")
    return save_figure(fig, path)


def positions_figure(trajectory: Trajectory, path: Path) -> Path:
    """Positions against time, continuous, sampling instants marked (the paper's Fig. 2)."""
    return _state_figure(trajectory, path, "x")


def velocities_figure(trajectory: Trajectory, path: Path) -> Path:
    """Velocities against time, continuous, sampling instants marked (the paper's Fig. 3)."""
    return _state_figure(trajectory, path, "v")


def inputs_figure(trajectory: Trajectory, path: Path) -> Path:
    """Inputs ``u_i(t)`` (affine on each interval) on a symmetric-log axis."""
    c = trajectory.config
    fig = new_figure()
    ax = fig.subplots()
    colours = agent_colours(c.n_agents)
    for i in range(c.n_agents):
        label = f"agent_{i}" if c.n_agents <= LEGEND_LIMIT else None
        ax.plot(trajectory.dense_times, trajectory.dense_u[:, i, 0], color=colours[i], lw=1.0, label=label)
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_xlabel("t (s)")
    unit = "m/s²" if c.model is None else "input units"
    ax.set_ylabel(f"input u_i(t) ({unit}){_component_note(trajectory)}")
    ax.set_title(f"inputs (symmetric log axis); peak |u| = {trajectory.metrics.peak_input:.3g} {unit}", fontsize=9)
    ax.grid(alpha=0.3)
    _legend(ax)
    return save_figure(fig, path)


def disagreement_figure(trajectory: Trajectory, path: Path) -> Path:
    """``D(t) / D(0)`` on a log axis, against time and against the sample index."""
    c = trajectory.config
    d0 = trajectory.disagreement[0] if trajectory.disagreement[0] > 0 else 1.0
    tiny = np.finfo(float).tiny
    fig = new_figure(9.0, 3.8)
    left, right = fig.subplots(1, 2)
    left.semilogy(
        trajectory.dense_times, np.maximum(trajectory.dense_disagreement / d0, tiny), lw=1.0, label="D(t)/D(0)"
    )
    left.semilogy(trajectory.times, np.maximum(trajectory.disagreement / d0, tiny), ".", ms=3, label="at t_k")
    left.axvline(c.settling_time, color="grey", lw=0.8, ls=":")
    left.set_xlabel("t (s)")
    left.set_ylabel("relative disagreement D(t)/D(0)")
    left.legend(fontsize=7)
    left.grid(alpha=0.3, which="both")
    k = np.arange(len(trajectory.times))
    right.semilogy(k, np.maximum(trajectory.disagreement / d0, tiny), ".-", ms=3, lw=0.8)
    right.set_xlabel("sampling instant k")
    right.set_ylabel("D(t_k)/D(0)")
    right.grid(alpha=0.3, which="both")
    fig.suptitle(
        f"{_disagreement_formula(c)}; deadline error D(T_s)/D(0) = {trajectory.metrics.relative_deadline_error:.2e} "
        f"with K = {c.n_intervals}",
        fontsize=9,
    )
    return save_figure(fig, path)


def _disagreement_formula(config) -> str:
    terms = ["e_x", "T_s e_v", "T_s² e_a", "T_s³ e_j"][: config.n_states]
    formula = "D = " + " + ".join(terms)
    return formula + " of z_i - e^(At) h_i" if config.formation is not None else formula


def write_figures(trajectory: Trajectory, out_dir: Path) -> list[Path]:
    """Write topology, positions, velocities, inputs, disagreement and overview PNGs into ``out_dir``.

    With formation offsets in two or more dimensions, also ``formation.png`` (:func:`formation_figure`).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    extra = []
    if trajectory.config.formation is not None and trajectory.config.dim >= 2:
        extra.append(formation_figure(trajectory, out_dir / "formation.png"))
    return [
        *extra,
        topology_figure(trajectory, out_dir / "topology.png"),
        positions_figure(trajectory, out_dir / "positions.png"),
        velocities_figure(trajectory, out_dir / "velocities.png"),
        inputs_figure(trajectory, out_dir / "inputs.png"),
        disagreement_figure(trajectory, out_dir / "disagreement.png"),
        overview_figure(trajectory, out_dir / "overview.png"),
    ]
