"""The engine's graph table: every episode's graphs as padded rows of in-neighbour slots.

Agent i of episode b measures, on the interval after ``t_k``, the agents ``j`` with an edge
``j -> i`` in that episode's graph ``G_{sigma(k)}`` (paper Section 2: ``sigma(k) = k mod m``
for periodic switching, or a uniform draw from the period for random switching). The table
stacks the distinct topologies' graphs once, on the host, and copies them to the device:

- ``neighbour_index`` ``(G, N, slots)``: the in-neighbours of each agent in each of the G
  distinct graphs, padded to the layout's ``slots`` with the agent itself (a gather of a
  padded slot then gives an exact zero relative measurement);
- ``mask_features`` ``(G, N, slots)``: 1 for a real in-neighbour, 0 for padding.

Episode b's graphs are rows ``offset[b] + (0 .. m_b - 1)``. :meth:`GraphTable.draw` picks the
row of every episode for the coming interval.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fxc_env.core.graphs import Topology


class GraphTable:
    """The graphs of B episodes and which one each plays on the coming interval.

    Args:
        topologies: one per episode (the same object for episodes that share it).
        slots: the observation layout's in-neighbour slots (at least every graph's max in-degree).
        backend: the engine's array backend.
        random_switching: draw each interval's graph uniformly from the period (else ``k mod m``).
    """

    def __init__(self, topologies: Sequence[Topology], slots: int, backend: Any, random_switching: bool) -> None:
        self.backend = backend
        self.random_switching = random_switching
        self.topologies = list(topologies)
        n = self.topologies[0].n_agents
        unique: dict[int, int] = {}
        index_blocks, mask_blocks, offsets, periods = [], [], [], []
        start = 0
        for topology in self.topologies:
            if id(topology) not in unique:
                unique[id(topology)] = start
                extra = slots - topology.max_in_degree
                own = np.broadcast_to(np.arange(n)[None, :, None], (topology.period, n, extra))
                index_blocks.append(np.concatenate([topology.neighbour_index, own], axis=2))
                mask_blocks.append(
                    np.concatenate([topology.neighbour_mask, np.zeros((topology.period, n, extra), bool)], axis=2)
                )
                start += topology.period
            offsets.append(unique[id(topology)])
            periods.append(topology.period)
        xp = backend.xp
        self.neighbour_index = backend.array(np.concatenate(index_blocks), dtype=xp.int64)
        self.mask_features = backend.array(np.concatenate(mask_blocks))
        self.offset_host = np.array(offsets)
        self.period_host = np.array(periods)
        self.offset = backend.array(self.offset_host, dtype=xp.int64)
        self.period = backend.array(self.period_host, dtype=xp.int64)
        #: One topology for all episodes: gathers take the fast path of a single graph.
        self.shared = len(unique) == 1
        #: Every episode plays row :attr:`graph` (one shared, periodic topology in lock step).
        self.same_graph = False
        self.graph = 0
        #: Each episode's row of the table on the coming interval, ``(B,)``.
        self.graph_ids: Any = None
        self._episode_index = xp.reshape(xp.arange(len(offsets), device=backend.device), (-1, 1, 1))
        self._blocks: dict[tuple[int, int], list] = {}

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_blocks"] = {}  # the fast path's slot-major copies, made again on first use
        return state

    def draw(self, clock: Any, switching_draw: Callable[[Any], Any]) -> None:
        """Each episode's graph on the coming interval: ``G_{k mod m}``, or ``switching_draw(periods)``.

        ``switching_draw`` maps the periods ``(B,)`` (host numpy on numpy, device tensor on
        torch) to each episode's draw in ``[0, m_b)`` (the engine's, seeded generator).
        """
        numpy_side = self.backend.is_numpy
        self.same_graph = self.shared and not self.random_switching and not clock.per_episode
        if self.same_graph:
            # One graph for every episode, known on the host.
            self.graph = int(self.offset_host[0] + clock.k % self.period_host[0])
        periods = self.period_host if numpy_side else self.period
        if self.random_switching:
            local = switching_draw(periods)
        else:
            local = clock.steps % self.period if clock.per_episode else clock.k % periods
        self.graph_ids = (self.offset_host if numpy_side else self.offset) + local

    def graph_indices(self) -> Any:
        """Index, within its own topology, of each episode's graph on the coming interval, ``(B,)``."""
        return self.graph_ids - self.offset

    def blocks(self, graph: int, block: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Row ``graph`` of the table in blocks of ``block`` agents, slot-major (numpy fast path, made once).

        Returns ``(start, index, mask)`` per block, ``index`` ``(slots, m)`` and ``mask``
        ``(slots, m)`` contiguous: a block's gather reads one contiguous run of indices.
        """
        key = (graph, block)
        if key not in self._blocks:
            index, mask = self.neighbour_index[graph].T, self.mask_features[graph].T
            n = index.shape[1]
            self._blocks[key] = [
                (
                    start,
                    np.ascontiguousarray(index[:, start : start + block]),
                    np.ascontiguousarray(mask[:, start : start + block]),
                )
                for start in range(0, n, block)
            ]
        return self._blocks[key]

    def gather(self, values: Any) -> tuple[Any, Any]:
        """In-neighbour rows of ``values`` ``(B, N, ...)`` on the coming interval, and their mask.

        Returns ``values[b, j]`` for every slot j of agent i, ``(B, N, slots, ...)``, and the
        mask ``(N, slots)`` (one graph for all) or ``(B, N, slots)``.
        """
        if self.same_graph:
            index = self.neighbour_index[self.graph]
            # numpy fast path: take with mode="clip" skips the bounds check (1.3x)
            rows = np.take(values, index, axis=1, mode="clip") if self.backend.is_numpy else values[:, index]
            return rows, self.mask_features[self.graph]
        index = self.neighbour_index[self.graph_ids]  # (B, N, slots)
        return values[self._episode_index, index], self.mask_features[self.graph_ids]
