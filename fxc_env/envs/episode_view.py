"""What the front ends record for ``render()``: the trails of episode 0 or of the first episodes
(:class:`EpisodeView`), or snapshots of a device batch (:class:`SnapshotView`); nothing without a render mode."""

from __future__ import annotations

from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.graphs import Topology
from fxc_env.engine.backend import to_host
from fxc_env.envs.rendering import DPI, SceneRenderer, tile_frames


class EpisodeView:
    """What a front end needs for ``render_mode``: the sampled history of its first episodes and a lazy renderer.

    Records nothing when ``render_mode`` is None. Pickles without its renderer (rebuilt on demand).

    Args:
        config: the settings.
        render_mode: None, ``"rgb_array"`` or ``"human"``.
        episodes: how many of the engine's first episodes to record (the batched envs' grid).
    """

    def __init__(self, config: EnvConfig, render_mode: str | None, episodes: int = 1) -> None:
        self.config = config
        self.render_mode = render_mode
        self.episodes = episodes
        #: ``(t, positions (G, N, dim), D(t)/D(0) (G,))`` at each recorded sampling instant.
        self.history: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._graphs: np.ndarray = np.zeros(0, dtype=np.int64)
        self._intervals: np.ndarray = np.zeros(0, dtype=np.int64)
        self._topologies: list[Topology] = []
        self._renderer: Any = None
        self._window: Any = None

    def start(self, engine: Any) -> None:
        """A new episode (or batch of them): the engine's state at ``t = 0``."""
        self.history = []
        if self.render_mode:
            self.record(engine)

    def record(self, engine: Any) -> None:
        """The engine's first episodes at its current sampling instant (nothing without a render mode)."""
        if not self.render_mode:
            return
        g = self.episodes
        z = np.asarray(engine.absolute_state()[:g])  # (G, N, n, dim)
        initial = np.asarray(engine.initial_disagreement[:g], dtype=float)
        current = np.asarray(engine.current_disagreement[:g], dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(initial > 0, current / np.where(initial > 0, initial, 1.0), np.nan)
        self.history.append((float(engine.time), z[:, :, 0].copy(), ratio))
        self._graphs = np.asarray(engine.graph_indices()[:g]).astype(np.int64)
        self._intervals = np.full(g, int(engine.k))
        self._topologies = list(engine.topologies[:g])

    def _draw(self, episode: int) -> np.ndarray:
        if not self.history:
            raise RuntimeError("render: there is no episode to draw yet; call reset() first")
        if self._renderer is None:
            self._renderer = SceneRenderer(self.config, markers=True)
        times = np.array([h[0] for h in self.history])
        positions = np.array([h[1][episode] for h in self.history])
        return self._renderer.draw(
            times,
            positions,
            ratio=float(self.history[-1][2][episode]),
            interval=int(self._intervals[episode]),
            graph=int(self._graphs[episode]),
            topology=self._topologies[episode],
            heading=f"{self._topologies[episode].name}: episode {episode}" if self.episodes > 1 else None,
        )

    def frames(self) -> list[np.ndarray]:
        """One ``(H, W, 3)`` uint8 frame per recorded episode (raises ``RuntimeError`` before any reset)."""
        if not self.history:
            raise RuntimeError("render: there is no episode to draw yet; call reset() first")
        return [self._draw(b) for b in range(len(self.history[0][2]))]

    def _shown(self, picture: np.ndarray) -> np.ndarray | None:
        """``picture``; ``human``: shown in the window instead, None."""
        if self.render_mode != "human":
            return picture
        import matplotlib.pyplot as plt

        if self._window is None:
            height, width = picture.shape[:2]
            figure = plt.figure(figsize=(width / DPI, height / DPI), dpi=DPI)
            ax = figure.add_axes((0, 0, 1, 1))
            ax.set_axis_off()
            self._window = (figure, ax.imshow(picture))
        else:
            self._window[1].set_data(picture)
        plt.pause(0.001)
        return None

    def frame(self) -> np.ndarray | None:
        """Episode 0's frame (``rgb_array``: ``(H, W, 3)`` uint8; ``human``: shown, None).

        Raises ``RuntimeError`` when no episode has started (nothing recorded).
        """
        return self._shown(self._draw(0))

    def grid(self) -> np.ndarray | None:
        """The recorded episodes' frames tiled (:func:`tile_frames`); ``human``: shown, None."""
        return self._shown(tile_frames(self.frames()))

    def close(self) -> None:
        self._renderer = None
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window[0])
            self._window = None

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_renderer": None, "_window": None}


class SnapshotView:
    """Frames of a batched engine whose episodes may keep their own clocks (the TorchRL env).

    Nothing is recorded on the step path: each :meth:`grid` call reads the first ``episodes``
    episodes' instants, states and ``D(t_k)/D(0)`` off the device, adds them to each episode's
    trail, then draws and tiles their frames. An episode whose instant went back to 0 or below
    its last one (a reset) starts a new trail; the same instant again replaces its entry. So
    calling it after every reset and step (TorchRL's ``PixelRenderTransform`` does) draws the
    trails through every sampling instant.

    Args:
        config: the settings.
        episodes: how many of the engine's first episodes to draw.
    """

    def __init__(self, config: EnvConfig, episodes: int) -> None:
        self.config = config
        self.episodes = episodes
        #: Per episode: ``(k, t, positions (N, dim), D(t_k)/D(0))`` at each recorded instant.
        self.trails: list[list[tuple[int, float, np.ndarray, float]]] = [[] for _ in range(episodes)]
        self._renderer: SceneRenderer | None = None

    def record(self, engine: Any) -> None:
        """Add the engine's first episodes at their current instants to their trails."""

        g = self.episodes
        steps = engine.steps
        instants = np.full(g, int(engine.k)) if steps is None else to_host(steps[:g]).astype(np.int64)
        times = np.asarray(self.config.schedule.times)[instants]
        positions = to_host(engine.absolute_state()[:g])[:, :, 0]
        initial = to_host(engine.initial_disagreement[:g]).astype(float)
        current = to_host(engine.current_disagreement[:g]).astype(float)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = np.where(initial > 0, current / np.where(initial > 0, initial, 1.0), np.nan)
        self._graphs = to_host(engine.graph_indices()[:g]).astype(np.int64)
        self._topologies = list(engine.topologies[:g])
        for b, trail in enumerate(self.trails):
            entry = (int(instants[b]), float(times[b]), positions[b].astype(float), float(ratios[b]))
            if not trail or entry[0] == 0 or entry[0] < trail[-1][0]:
                trail[:] = [entry]
            elif entry[0] == trail[-1][0]:
                trail[-1] = entry
            else:
                trail.append(entry)

    def grid(self, engine: Any) -> np.ndarray:
        """Record (:meth:`record`), then the episodes' frames tiled (:func:`tile_frames`): ``(H, W, 3)`` uint8."""
        self.record(engine)
        if self._renderer is None:
            self._renderer = SceneRenderer(self.config, markers=True)
        frames = []
        for b, trail in enumerate(self.trails):
            topology = self._topologies[b]
            frames.append(
                self._renderer.draw(
                    np.array([entry[1] for entry in trail]),
                    np.array([entry[2] for entry in trail]),
                    ratio=trail[-1][3],
                    interval=trail[-1][0],
                    graph=int(self._graphs[b]),
                    topology=topology,
                    heading=f"{topology.name}: episode {b}" if self.episodes > 1 else None,
                )
            )
        return tile_frames(frames)

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_renderer": None}
