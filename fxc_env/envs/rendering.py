"""Drawing: the environment's frames and the directed graphs (matplotlib, headless).

``rgb_array`` frames are drawn on an Agg canvas without pyplot, so they work on machines
without a display; ``human`` mode opens a pyplot window when the backend is interactive.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.graphs import Topology

if TYPE_CHECKING:
    from matplotlib.axes import Axes

#: Graphs with more agents than this are summarised in text instead of drawn.
DRAW_GRAPH_LIMIT = 60


def circle_layout(n_agents: int) -> np.ndarray:
    """Agent positions on the unit circle, agent 0 at the top, clockwise; ``(N, 2)``."""
    angle = np.pi / 2 - 2 * np.pi * np.arange(n_agents) / max(n_agents, 1)
    return np.stack([np.cos(angle), np.sin(angle)], axis=1)


def draw_graph(ax: Axes, topology: Topology, graph: int, *, title: str | None = None, one_based: bool = False) -> None:
    """Draw graph ``graph`` of the period: nodes on a circle, arrows ``j -> i`` (i receives from j)."""
    from matplotlib.patches import FancyArrowPatch

    n = topology.n_agents
    ax.set_aspect("equal")
    ax.set_axis_off()
    ax.set_xlim(-1.35, 1.35)
    ax.set_ylim(-1.35, 1.35)
    if title:
        ax.set_title(title, fontsize=10)
    if n > DRAW_GRAPH_LIMIT:
        edges = len(topology.edges[graph])
        ax.text(0, 0, f"{n} agents\n{edges} edges", ha="center", va="center")
        return
    where = circle_layout(n)
    for j, i in topology.edges[graph]:
        arrow = FancyArrowPatch(
            where[j],
            where[i],
            arrowstyle="-|>",
            mutation_scale=12,
            shrinkA=9,
            shrinkB=9,
            color="tab:blue",
            lw=1.3,
            connectionstyle="arc3,rad=0.12",
        )
        ax.add_patch(arrow)
    ax.scatter(where[:, 0], where[:, 1], s=260, color="white", edgecolor="black", zorder=3)
    offset = 1 if one_based else 0
    for node, (px, py) in enumerate(where):
        ax.text(px, py, str(node + offset), ha="center", va="center", fontsize=8, zorder=4)


def agent_colours(n_agents: int) -> list:
    """One colour per agent (tab10 cycled)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(i % 10) for i in range(n_agents)]


class EpisodeRenderer:
    """Frames of the episode so far: positions and velocities (first component) and the current graph."""

    def __init__(self, config: EnvConfig, *, interactive: bool = False) -> None:
        self.config = config
        self.interactive = interactive
        if interactive:
            import matplotlib.pyplot as plt

            self._plt = plt
            self.figure = plt.figure(figsize=(9, 3.2), dpi=80)
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            self.figure = Figure(figsize=(9, 3.2), dpi=80)
            FigureCanvasAgg(self.figure)

    def draw(
        self, history: Sequence[tuple[float, np.ndarray, np.ndarray]], graph: int, topology: Topology | None = None
    ) -> np.ndarray:
        """Redraw and return the frame as an ``(H, W, 3)`` uint8 array.

        ``graph`` indexes ``topology`` (the episode's own, e.g. a family's draw; default the config's).
        """
        c = self.config
        fig = self.figure
        fig.clear()
        axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.4, 1.4, 1]})
        times = np.array([h[0] for h in history])
        xs = np.array([h[1][:, 0] for h in history])
        vs = np.array([h[2][:, 0] for h in history])
        colours = agent_colours(c.n_agents)
        for ax, values, label in ((axes[0], xs, "position x"), (axes[1], vs, "velocity v")):
            shown = min(c.n_agents, 30)
            for i in range(shown):
                ax.plot(times, values[:, i], marker=".", ms=3, lw=1, color=colours[i])
            ax.set_xlim(0, c.settling_time)
            ax.set_xlabel("t (s)")
            ax.set_ylabel(label + (" (1st component)" if c.dim > 1 else ""))
            ax.grid(alpha=0.3)
        k = len(history) - 1
        draw_graph(axes[2], c.topology if topology is None else topology, graph, title=f"k = {k}, graph G_{graph}")
        fig.tight_layout()
        fig.canvas.draw()
        frame = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        if self.interactive:
            self._plt.pause(0.001)
        return frame

    def close(self) -> None:
        if self.interactive:
            self._plt.close(self.figure)


class EpisodeView:
    """What a front end needs for ``render_mode``: the sampled history of episode 0 and a lazy figure.

    Records nothing when ``render_mode`` is None. Pickles without its figure (rebuilt on demand).
    """

    def __init__(self, config: EnvConfig, render_mode: str | None) -> None:
        self.config = config
        self.render_mode = render_mode
        self.history: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._renderer: Any = None

    def start(self, x0: np.ndarray, v0: np.ndarray) -> None:
        """A new episode from ``(N, dim)`` states at ``t = 0``."""
        self.history = [(0.0, x0.copy(), v0.copy())] if self.render_mode else []

    def record(self, t: float, x: np.ndarray, v: np.ndarray) -> None:
        """The ``(N, dim)`` states at sampling instant ``t``; draws at once in ``human`` mode."""
        if self.render_mode:
            self.history.append((t, x.copy(), v.copy()))

    def frame(self, graph: int, topology: Topology | None = None) -> np.ndarray | None:
        """The frame (``rgb_array``: ``(H, W, 3)`` uint8; ``human``: shown, None) with graph ``graph`` drawn.

        ``topology``: the episode's own (a family's draw); default the config's. Raises
        ``RuntimeError`` when no episode has started (nothing recorded).
        """
        if not self.history:
            raise RuntimeError("render: there is no episode to draw yet; call reset() first")
        if self._renderer is None:
            self._renderer = EpisodeRenderer(self.config, interactive=self.render_mode == "human")
        frame = self._renderer.draw(self.history, graph, topology)
        return frame if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_renderer": None}
