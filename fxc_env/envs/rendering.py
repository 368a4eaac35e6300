"""Drawing: the environments' frames, the videos' frames and the directed graphs (matplotlib, headless).

Frames are drawn on an Agg canvas without pyplot (no display needed). A :class:`SceneRenderer`
builds its figure and artists once and then only changes their data; nothing is drawn on the
stepping path when ``render_mode`` is None. What a frame shows: docs: video.md, "Video".
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.graphs import Topology
from fxc_env.core.validation import ArgumentError

if TYPE_CHECKING:
    from matplotlib.axes import Axes

#: Graphs with more agents than this are summarised in text instead of drawn on a circle.
DRAW_GRAPH_LIMIT = 60
#: Agents drawn in a frame (trails, markers, edges); beyond this the first ones are drawn, and the frame says so.
DRAW_AGENT_LIMIT = 1000
#: Default frame size ``(width, height)`` in pixels: the environments' frames and the videos'.
FRAME_SIZE = (640, 360)
#: Smallest and largest frame side accepted (pixels).
FRAME_SIDE_RANGE = (64, 4096)
#: Episodes a batched environment records and tiles (the first ones).
GRID_EPISODES = 16
#: Dots per inch of every frame (pixels per figure inch).
DPI = 100


def circle_layout(n_agents: int) -> np.ndarray:
    """Agent positions on the unit circle, agent 0 at the top, clockwise; ``(N, 2)``."""
    angle = np.pi / 2 - 2 * np.pi * np.arange(n_agents) / max(n_agents, 1)
    return np.stack([np.cos(angle), np.sin(angle)], axis=1)


def _graph_arrow(start: np.ndarray, end: np.ndarray, colour: Any = "tab:blue"):
    from matplotlib.patches import FancyArrowPatch

    return FancyArrowPatch(
        start,
        end,
        arrowstyle="-|>",
        mutation_scale=12,
        shrinkA=9,
        shrinkB=9,
        color=colour,
        lw=1.3,
        connectionstyle="arc3,rad=0.12",
    )


def draw_graph(ax: Axes, topology: Topology, graph: int, *, title: str | None = None, one_based: bool = False) -> None:
    """Draw graph ``graph`` of the period: nodes on a circle, arrows ``j -> i`` (i receives from j)."""
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
        ax.add_patch(_graph_arrow(where[j], where[i]))
    ax.scatter(where[:, 0], where[:, 1], s=260, color="white", edgecolor="black", zorder=3)
    offset = 1 if one_based else 0
    for node, (px, py) in enumerate(where):
        ax.text(px, py, str(node + offset), ha="center", va="center", fontsize=8, zorder=4)


def agent_colours(n_agents: int) -> list:
    """One colour per agent (tab10 cycled)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"]
    return [cmap(i % 10) for i in range(n_agents)]


def frame_size(name: str, value: Any) -> tuple[int, int]:
    """``value`` as a frame size ``(width, height)`` in pixels: a pair of integers or ``"WIDTHxHEIGHT"``.

    Each side in :data:`FRAME_SIDE_RANGE`; refused naming ``name`` otherwise.
    """
    low, high = FRAME_SIDE_RANGE
    expected = f"a frame size WIDTHxHEIGHT in pixels, each side an integer in [{low}, {high}]"
    pair = value
    if isinstance(value, str):
        parts = value.lower().split("x")
        if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
            raise ArgumentError(f"{name}: expected {expected} (e.g. '640x360'), got {value!r}")
        pair = tuple(int(p) for p in parts)
    if (
        not isinstance(pair, Sequence)
        or len(pair) != 2
        or not all(isinstance(p, int | np.integer) and not isinstance(p, bool) for p in pair)
        or not all(low <= p <= high for p in pair)
    ):
        raise ArgumentError(f"{name}: expected {expected}, got {value!r}")
    return int(pair[0]), int(pair[1])


def tile_frames(frames: Sequence[np.ndarray]) -> np.ndarray:
    """One ``(rows H, cols W, 3)`` uint8 picture of ``(H, W, 3)`` frames, row by row.

    The layout of Stable-Baselines3's ``tile_images``: ``rows = ceil(sqrt(n))``,
    ``cols = ceil(n / rows)``; the empty cells are white.
    """
    stack = np.asarray(frames)
    n, height, width, channels = stack.shape
    rows = int(np.ceil(np.sqrt(n)))
    cols = int(np.ceil(n / rows))
    grid = np.full((rows * cols, height, width, channels), 255, dtype=np.uint8)
    grid[:n] = stack
    return (
        grid.reshape(rows, cols, height, width, channels)
        .transpose(0, 2, 1, 3, 4)
        .reshape(rows * height, cols * width, channels)
    )


def blank_frame(message: str, size: Any = FRAME_SIZE) -> np.ndarray:
    """A white ``(H, W, 3)`` uint8 frame that shows ``message`` (in place of a frame that is not drawn)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    width, height = frame_size("size", size)
    figure = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
    FigureCanvasAgg(figure)
    figure.text(0.5, 0.5, message, ha="center", va="center", wrap=True, fontsize=max(6.0, height / 36))
    figure.canvas.draw()
    frame = np.full((height, width, 3), 255, dtype=np.uint8)
    drawn = np.asarray(figure.canvas.buffer_rgba())[:height, :width, :3]
    frame[: drawn.shape[0], : drawn.shape[1]] = drawn
    return frame


def _padded(low: float, high: float, rounded: bool, fraction: float = 0.08) -> tuple[float, float]:
    span = high - low
    pad = fraction * span if span > 0 else max(abs(low), 1.0) * 0.5
    low, high = low - pad, high + pad
    if rounded:
        step = 10.0 ** np.floor(np.log10(high - low)) / 2
        low, high = float(np.floor(low / step) * step), float(np.ceil(high / step) * step)
    return low, high


def data_limits(positions: np.ndarray, rounded: bool = False) -> tuple[float, ...]:
    """Padded view limits of positions ``(..., N, dim)``: ``(y0, y1)`` in 1-D, ``(x0, x1, y0, y1)`` in the plane.

    ``rounded``: the ends rounded outwards to multiples of half the power of ten below the span.
    """
    finite = positions[np.isfinite(positions).all(axis=-1)]
    if finite.size == 0:
        finite = np.zeros((1, positions.shape[-1]))
    axes = 1 if positions.shape[-1] == 1 else 2
    return tuple(
        value for a in range(axes) for value in _padded(float(finite[:, a].min()), float(finite[:, a].max()), rounded)
    )


class SceneRenderer:
    """Frames of one episode at given instants, drawn on a reused Agg canvas.

    The still part of the picture (axes, ticks, labels, the graph panel's nodes) is drawn once
    and kept as a background while the view limits and the topology stay the same; each frame
    restores it and draws only the moving artists (trails, markers, arrows, texts) over it.
    Without given limits the view follows the trails, its ends rounded outwards to steps of
    half a power of ten of the span (so the background is seldom redrawn, and the same trails
    always give the same frame).

    Args:
        config: the episode's settings (``dim`` picks the layout, ``T_s`` the time axis).
        size: ``(width, height)`` pixels of the frames (:func:`frame_size`).
        title: the frame's heading (default: the topology's name, given at each :meth:`draw`).
        markers: dots at the trails' vertices (the environments' frames, whose trails join sampling instants).
    """

    def __init__(
        self, config: EnvConfig, size: Any = FRAME_SIZE, *, title: str | None = None, markers: bool = False
    ) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.config = config
        self.size = frame_size("size", size)
        self.title = title
        width, height = self.size
        self.figure = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
        FigureCanvasAgg(self.figure)
        self.n_shown = min(config.n_agents, DRAW_AGENT_LIMIT)
        self.colours = agent_colours(self.n_shown)
        self.font = max(6.0, min(width / 60, height / 34))
        self.one_d = config.dim == 1
        fig = self.figure
        self.heading = fig.text(0.01, 0.985, "", ha="left", va="top", fontsize=self.font * 1.05)
        self.clock = fig.text(0.01, 0.92, "", ha="left", va="top", fontsize=self.font, family="monospace")
        self._build_axes(markers)
        self.markers = markers
        self.dots = self.ax.scatter(
            np.zeros(self.n_shown), np.zeros(self.n_shown), s=28, c=self.colours, edgecolors="black", lw=0.5, zorder=3
        )
        self.ax.tick_params(labelsize=self.font * 0.9)
        self.ax.grid(alpha=0.3)
        self._topology: Topology | None = None
        self._graph_patches: list[list[Any]] = []
        self._graph_summary: Any = None
        self._background: Any = None
        self._background_key: Any = None
        self._moving = [self.clock, self.dots]
        if self.one_d:
            self._moving += [*self.lines, self.now]
        else:
            self._moving += [self.trails, self.edges, self.heads] + ([self.vertices] if markers else [])
        for artist in self._moving:
            artist.set_animated(True)

    def _build_axes(self, markers: bool) -> None:
        """The axes and the trails' artists: position against time with a graph panel (1-D), or the plane."""
        width, fig, config = self.size[0], self.figure, self.config
        left = max(0.09, 62 / width)  # room for the tick labels and the axis label
        if self.one_d:
            self.ax = fig.add_axes((left, 0.14, 0.67 - left, 0.68))
            self.graph_ax = fig.add_axes((0.69, 0.04, 0.30, 0.80))
            self.graph_ax.set_axis_off()
            self.graph_ax.set_aspect("equal")
            self.graph_ax.set_xlim(-1.3, 1.3)
            self.graph_ax.set_ylim(-1.55, 1.3)
            style = {"marker": ".", "ms": 3} if markers else {}
            self.lines = [self.ax.plot([], [], lw=1.2, color=c, **style)[0] for c in self.colours]
            self.now = self.ax.axvline(0.0, color="grey", lw=0.8, ls=":")
            self.ax.set_xlim(0.0, config.settling_time)
            self.ax.set_xlabel("t (s)", fontsize=self.font)
            self.ax.set_ylabel("position x_i (m)", fontsize=self.font)
        else:
            from matplotlib.collections import LineCollection, PolyCollection

            self.ax = fig.add_axes((left, 0.14, 0.98 - left, 0.70))
            self.trails = LineCollection([], colors=self.colours, linewidths=1.0, alpha=0.8)
            self.edges = LineCollection([], colors="0.25", linewidths=0.9, zorder=2)
            self.heads = PolyCollection([], facecolors="0.25", edgecolors="none", zorder=2)
            for artist in (self.trails, self.edges, self.heads):
                self.ax.add_collection(artist)
            if markers:
                self.vertices = self.ax.scatter([], [], s=4, c="0.5", zorder=1)
            second = f" (first two of dim = {config.dim})" if config.dim > 2 else ""
            self.ax.set_xlabel("x_i, first axis (m)" + second, fontsize=self.font)
            self.ax.set_ylabel("x_i, second axis (m)", fontsize=self.font)

    # ------------------------------------------------------------ the graph panel (1-D)
    def _set_topology(self, topology: Topology) -> None:
        """Build the arrows of every graph of the period once (then only their visibility changes)."""
        ax = self.graph_ax
        for patches in self._graph_patches:
            for patch in patches:
                patch.remove()
        for artist in [*ax.collections, *ax.texts]:
            artist.remove()
        self._graph_patches = []
        n = topology.n_agents
        ax.text(0, -1.52, "current graph: arrow j -> i", ha="center", va="bottom", fontsize=self.font * 0.9)
        if n > DRAW_GRAPH_LIMIT:
            self._graph_summary = ax.text(0, 0, "", ha="center", va="center", fontsize=self.font, animated=True)
        else:
            self._graph_summary = None
            where = circle_layout(n)
            for edges in topology.edges:
                patches = [ax.add_patch(_graph_arrow(where[j], where[i], "0.25")) for j, i in edges]
                for patch in patches:
                    patch.set_animated(True)
                self._graph_patches.append(patches)
            ax.scatter(where[:, 0], where[:, 1], s=190, c=agent_colours(n), edgecolors="black", lw=0.6, zorder=3)
            for node, (px, py) in enumerate(where):
                ax.text(px, py, str(node), ha="center", va="center", fontsize=self.font * 0.8, zorder=4)
        self._topology = topology

    def _show_graph(self, topology: Topology, graph: int) -> list[Any]:
        """Set the graph panel to ``G_graph``; returns its moving artists (the arrows and notes)."""
        if topology is not self._topology:
            self._set_topology(topology)
        edges = len(topology.edges[graph])
        if self._graph_summary is not None:
            self._graph_summary.set_text(f"{topology.n_agents} agents\ngraph G_{graph}\n{edges} edges")
            return [self._graph_summary]
        return self._graph_patches[graph]

    # ------------------------------------------------------------ the plane (2-D and more)
    def _plane_limits(self, limits: tuple[float, ...]) -> tuple[float, float, float, float]:
        """``limits`` widened so that one metre spans as many pixels on both axes."""
        x0, x1, y0, y1 = limits
        bbox = self.ax.get_position()
        width_px = bbox.width * self.size[0]
        height_px = bbox.height * self.size[1]
        per_pixel = max((x1 - x0) / width_px, (y1 - y0) / height_px)
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        hx, hy = per_pixel * width_px / 2, per_pixel * height_px / 2
        return cx - hx, cx + hx, cy - hy, cy + hy

    def _plane_edges(self, now: np.ndarray, topology: Topology, graph: int, per_pixel: float) -> None:
        """Arrows ``j -> i`` between the agents' current positions, shortened by the markers' radius."""
        edges = topology.edges[graph]
        if len(edges):
            edges = edges[(edges[:, 0] < self.n_shown) & (edges[:, 1] < self.n_shown)]
        if not len(edges):
            self.edges.set_segments([])
            self.heads.set_verts([])
            return
        start, end = now[edges[:, 0]], now[edges[:, 1]]
        delta = end - start
        length = np.hypot(delta[:, 0], delta[:, 1])
        shrink, head, half = 6 * per_pixel, 8 * per_pixel, 3.5 * per_pixel
        keep = length > 2 * shrink + head
        start, end, delta, length = start[keep], end[keep], delta[keep], length[keep]
        unit = delta / np.maximum(length, np.finfo(float).tiny)[:, None]
        normal = np.stack([-unit[:, 1], unit[:, 0]], axis=1)
        tip = end - shrink * unit
        base = tip - head * unit
        tail = start + shrink * unit
        self.edges.set_segments(np.stack([tail, base], axis=1))
        self.heads.set_verts(np.stack([tip, base + half * normal, base - half * normal], axis=1))

    # ------------------------------------------------------------ one frame
    def draw(
        self,
        times: np.ndarray,
        positions: np.ndarray,
        *,
        ratio: float,
        interval: int,
        graph: int,
        topology: Topology,
        limits: tuple[float, ...] | None = None,
        heading: str | None = None,
    ) -> np.ndarray:
        """The frame at ``times[-1]`` as an ``(H, W, 3)`` uint8 array.

        Args:
            times: ``(P,)`` seconds, the trails' instants, the last one now.
            positions: ``(P, N, dim)`` absolute positions (m) at ``times``.
            ratio: ``D(t)/D(0)`` now (nan when ``D(0) = 0``).
            interval: k, the interval ``[t_k, t_{k+1})`` now is in (K at ``T_s``).
            graph: the index in ``topology.edges`` of the graph of that interval.
            topology: the episode's graphs.
            limits: fixed view limits (:func:`data_limits`); default the trails' own.
            heading: the frame's heading (default the renderer's title, else the topology's name).
        """
        c = self.config
        shown = positions[:, : self.n_shown]
        t = float(times[-1])
        limits = data_limits(shown, rounded=True) if limits is None else limits
        heading = heading or self.title or topology.name
        if self.n_shown < c.n_agents:
            heading += f" (agents 0-{self.n_shown - 1} of {c.n_agents} drawn)"
        self.heading.set_text(heading)
        shown_ratio = "n/a" if not np.isfinite(ratio) else f"{ratio:.2e}"
        self.clock.set_text(
            f"t = {t:6.3f}/{c.settling_time:g} s  k = {interval}/{c.n_intervals}  G_{graph}  D(t)/D(0) = {shown_ratio}"
        )
        if self.one_d:
            for i, line in enumerate(self.lines):
                line.set_data(times, shown[:, i, 0])
            self.dots.set_offsets(np.column_stack([np.full(self.n_shown, t), shown[-1, :, 0]]))
            self.now.set_xdata([t, t])
            self.ax.set_ylim(*limits)
            moving = self._show_graph(topology, graph)
        else:
            x0, x1, y0, y1 = self._plane_limits(limits)
            self.ax.set_xlim(x0, x1)
            self.ax.set_ylim(y0, y1)
            plane = shown[..., :2]
            self.trails.set_segments(list(np.swapaxes(plane, 0, 1)))
            if self.markers:
                self.vertices.set_offsets(plane.reshape(-1, 2))
            self.dots.set_offsets(plane[-1])
            per_pixel = (x1 - x0) / (self.ax.get_position().width * self.size[0])
            self._plane_edges(plane[-1], topology, graph, per_pixel)
            moving = []
        return self._capture(heading, moving)

    def _capture(self, heading: str, moving: list[Any]) -> np.ndarray:
        """Draw the moving artists over the kept background (redrawn when the view changed); the pixels."""
        canvas = self.figure.canvas
        key = (self.ax.get_xlim(), self.ax.get_ylim(), id(self._topology), heading)
        if key != self._background_key:
            canvas.draw()  # the still part only: the moving artists are animated
            self._background = canvas.copy_from_bbox(self.figure.bbox)
            self._background_key = key
        else:
            canvas.restore_region(self._background)
        for artist in [*self._moving, *moving]:
            self.figure.draw_artist(artist)
        frame = np.asarray(canvas.buffer_rgba())[..., :3]
        width, height = self.size
        if frame.shape[:2] != (height, width):  # rounding of inches * dpi: pad or crop to the size asked for
            fixed = np.full((height, width, 3), 255, dtype=np.uint8)
            h, w = min(height, frame.shape[0]), min(width, frame.shape[1])
            fixed[:h, :w] = frame[:h, :w]
            return fixed
        return frame.copy()
