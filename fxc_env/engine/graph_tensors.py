"""The coming interval's graph of every episode as edge tensors, for graph neural networks (docs: graph-tensors.md, "Graph tensors").

Agent i of episode b measures, on the interval after ``t_k``, every in-neighbour j of that
episode's current graph ``G_{sigma(k)}`` (paper Section 2; ``sigma(k) = k mod m`` for periodic
switching): one message ``j -> i`` per edge. :func:`graph_tensors` lists those edges in PyTorch
Geometric's convention, batched first, on the engine's backend (no read off the device), as the
fields of :class:`GraphTensors` (their shapes and dtypes).

``E`` is the largest edge count of any graph in the engine's graph table, or a given ``width``
(:func:`edge_capacity`). Edges come first in each episode, sorted by target then source;
padding, the edge ``N -> N`` with zero features, follows, so a summing message pass over ``N + 1``
node rows needs no mask; an edge lost to ``link_dropout`` is not listed. ``edge_attr`` is read
out of the observation itself (``F = n dim``, normalized or raw as ``obs_mode`` says; docs:
graph-tensors.md, "Graph tensors").
"""

from __future__ import annotations

import weakref
from typing import Any, NamedTuple

import numpy as np

from fxc_env.core.validation import ArgumentError

#: The names of :class:`GraphTensors`, in order (the TorchRL environment's root keys).
GRAPH_TENSOR_KEYS = ("edge_index", "edge_mask", "n_edges", "edge_attr")


class GraphTensors(NamedTuple):
    """Every episode's current graph as edge tensors, padded to ``E`` edges (the module says how)."""

    #: ``(B, 2, E)`` int64: row 0 source j, row 1 target i.
    edge_index: Any
    #: ``(B, E)`` bool: True for a real edge.
    edge_mask: Any
    #: ``(B,)`` int64: the number of real edges (they come first).
    n_edges: Any
    #: ``(B, E, F)``: the measured relative rows ``z_j - z_i`` in the observation's scaling.
    edge_attr: Any


def edge_feature_size(config: Any) -> int:
    """``F``, the numbers per edge in ``edge_attr``: the observation's row size ``n dim``."""
    return int(config.layout.row_size)


def max_edges(topologies: Any) -> int:
    """The largest edge count over every graph of ``topologies`` (:class:`~fxc_env.core.graphs.Topology` objects)."""
    return max((len(edges) for topology in topologies for edges in topology.edges), default=0)


def edge_capacity(config: Any) -> int:
    """The ``E`` a front end pads to, the same at every reset: fixed shapes for specs and buffers.

    A fixed topology: its largest graph's edge count. A family (a new graph every reset): ``N
    slots``, the most edges an observation can hold (every agent's slots filled).
    """
    return int(config.n_agents * config.layout.slots) if config.family is not None else max_edges([config.topology])


class _EdgeTable:
    """One graph table's edges, one row per graph of the table, made once on the host and copied to the device.

    ``index`` ``(G, 2, E)``, ``mask`` ``(G, E)``, ``count`` ``(G,)`` and ``slot`` ``(G, E)``: the
    position ``i * slots + r`` of each edge in the flat ``(N * slots)`` rows of an observation.
    """

    def __init__(self, graphs: Any, slots: int, width: int | None, n_agents: int) -> None:
        rows: dict[int, Any] = {}
        for offset, topology in zip(graphs.offset_host.tolist(), graphs.topologies, strict=True):
            rows.setdefault(int(offset), topology)
        blocks = [edges for _, topology in sorted(rows.items()) for edges in topology.edges]
        largest = max((len(edges) for edges in blocks), default=0)
        if width is not None and width < largest:
            raise ArgumentError(
                f"width: a graph of the engine has {largest} edges; expected at least that, got {width}"
            )
        width = largest if width is None else width
        g = len(blocks)
        index = np.full((g, 2, width), n_agents, dtype=np.int64)
        mask = np.zeros((g, width), dtype=bool)
        count = np.zeros(g, dtype=np.int64)
        slot = np.zeros((g, width), dtype=np.int64)
        for row, edges in enumerate(blocks):
            e = len(edges)
            sources, targets = edges[:, 0], edges[:, 1]
            # Edges are sorted by target then source, as the slots are (core.graphs): the slot of
            # an edge is its rank among the target's edges.
            first = np.searchsorted(targets, targets, side="left")
            index[row, 0, :e], index[row, 1, :e] = sources, targets
            mask[row, :e] = True
            count[row] = e
            slot[row, :e] = targets * slots + (np.arange(e) - first)
        backend, xp = graphs.backend, graphs.backend.xp
        self.width = width
        self.index = backend.array(index, dtype=xp.int64)
        self.mask = backend.array(mask, dtype=xp.bool)
        self.count = backend.array(count, dtype=xp.int64)
        self.slot = backend.array(slot, dtype=xp.int64)
        self.episodes = xp.reshape(xp.arange(backend.n_episodes, dtype=xp.int64, device=backend.device), (-1, 1))


#: Each live graph table's edges by padded width (made at their first use; dropped with the table).
_TABLES: weakref.WeakKeyDictionary[Any, dict[int | None, _EdgeTable]] = weakref.WeakKeyDictionary()


def _edge_table(engine: Any, width: int | None) -> _EdgeTable:
    tables = _TABLES.setdefault(engine.graphs, {})
    if width not in tables:
        tables[width] = _EdgeTable(engine.graphs, engine.layout.slots, width, engine.config.n_agents)
    return tables[width]


def graph_tensors(engine: Any, observations: Any = None, width: int | None = None) -> GraphTensors:
    """Every episode's graph on the coming interval as :class:`GraphTensors`, on the engine's backend.

    Args:
        engine: a :class:`~fxc_env.engine.ConsensusEngine` after its reset (its current graphs,
            which follow the switching schedule, and after a partial reset each episode's clock).
        observations: the engine's flat observations at ``t_k``, ``(B, N, obs_size)``, as the
            caller already holds them (any dtype: ``edge_attr`` takes it); None computes them
            (:meth:`~fxc_env.engine.ConsensusEngine.observations`).
        width: pad ``E`` to at least this (:func:`edge_capacity` keeps shapes fixed across resets
            that draw new graphs); None: the largest graph of the engine's table.

    The edge lists of the engine's graph table are made once (on the host, at the first call
    after a reset that changed the topologies) and indexed by each episode's current graph;
    ``edge_attr`` is a gather of the observation's rows. Nothing is read off the device.
    """
    table = _edge_table(engine, width)
    layout, xp = engine.layout, engine.xp
    ids = engine.graphs.graph_ids
    if not engine.is_numpy:
        ids = xp.asarray(ids, dtype=xp.int64, device=engine.device)
    edge_index, edge_mask, n_edges, slot = table.index[ids], table.mask[ids], table.count[ids], table.slot[ids]
    if observations is None:
        observations = engine.observations()
    b, n = observations.shape[0], engine.config.n_agents
    rows = xp.reshape(observations[..., : layout.rows_end], (b, n * layout.slots, layout.row_size))
    if engine.config.link_dropout > 0:
        # Links lost at t_k (observation mask 0) are not received: drop them, keep the rest first.
        received = xp.reshape(observations[..., layout.rows_end : layout.mask_end], (b, n * layout.slots))
        edge_mask = edge_mask & (received[table.episodes, slot] > 0)
        order = xp.argsort(xp.astype(~edge_mask, xp.int8), axis=1, stable=True)
        edge_mask = xp.take_along_axis(edge_mask, order, axis=1)
        slot = xp.take_along_axis(slot, order, axis=1)
        edge_index = xp.take_along_axis(edge_index, xp.stack([order, order], axis=1), axis=2)
        edge_index = xp.where(edge_mask[:, None, :], edge_index, xp.full_like(edge_index, n))
        n_edges = xp.sum(xp.astype(edge_mask, xp.int64), axis=1)
    edge_attr = rows[table.episodes, slot]
    edge_attr = xp.where(edge_mask[..., None], edge_attr, xp.zeros_like(edge_attr))
    return GraphTensors(edge_index, edge_mask, n_edges, edge_attr)


def episode_graph(tensors: GraphTensors, episode: int = 0) -> tuple[Any, Any]:
    """One episode's ``edge_index`` ``(2, E_b)`` and ``edge_attr`` ``(E_b, F)`` without padding (a host read on torch)."""
    count = int(tensors.n_edges[episode])
    return tensors.edge_index[episode, :, :count], tensors.edge_attr[episode, :count]
