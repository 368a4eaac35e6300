"""Communication topologies: fixed or periodically switching directed graphs.

Convention (paper Section 2): an edge ``(j, i)`` means **agent i receives from
agent j**, so ``a_ij = 1`` and ``j`` is an in-neighbour of ``i``. Nodes are 0-based.
A *period* ``G_0, ..., G_{m-1}`` is used by sample index: ``G_{k mod m}`` is active on
``[t_k, t_{k+1})``. A fixed topology is a period of length one.

Everything here is pure numpy/scipy and costs O(N + |E|) except the dense matrices
(:meth:`Topology.averaging_matrix`, :meth:`Topology.consensus_weights`), which are for
small N (the paper's example, tests and plots).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from fxc_env.core import validation
from fxc_env.core.graph_kinds import GRAPH_KINDS, TOPOLOGY_NAMES
from fxc_env.core.validation import ArgumentError, ArgumentTypeError

#: Largest N for which :meth:`Topology.consensus_weights` builds dense matrices.
DENSE_LIMIT = 2000


@dataclass(frozen=True, eq=False)
class Topology:
    """A period of directed graphs on ``n_agents`` nodes.

    Attributes:
        n_agents: number of agents N.
        edges: one ``(E_g, 2)`` int64 array per graph of the period, rows ``(j, i)``
            (i receives from j), sorted by receiver then sender, no duplicates.
        name: a short label for tables and plots.
        note: provenance, e.g. that ``paper_fig1`` is our reconstruction of the lost figure.
    """

    n_agents: int
    edges: tuple[np.ndarray, ...]
    name: str = "custom"
    note: str = ""
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @property
    def period(self) -> int:
        """Number m of graphs in the switching period (1 for a fixed graph)."""
        return len(self.edges)

    @property
    def in_degree(self) -> np.ndarray:
        """In-degrees ``d_i`` of every graph, shape ``(m, N)``."""
        if "in_degree" not in self._cache:
            self._cache["in_degree"] = np.stack([np.bincount(e[:, 1], minlength=self.n_agents) for e in self.edges])
        return self._cache["in_degree"]

    @property
    def max_in_degree(self) -> int:
        """Largest in-degree over the whole period (the observation's row count)."""
        return int(self.in_degree.max(initial=0))

    @property
    def neighbour_index(self) -> np.ndarray:
        """In-neighbours of each agent, shape ``(m, N, d_max)``, ascending.

        Unused slots hold the agent's own index, so a gather of ``x_j - x_i`` gives
        exactly zero there; :attr:`neighbour_mask` marks the real rows.
        """
        if "neighbour_index" not in self._cache:
            self._build_neighbour_arrays()
        return self._cache["neighbour_index"]

    @property
    def neighbour_mask(self) -> np.ndarray:
        """``True`` where :attr:`neighbour_index` holds a real in-neighbour, ``(m, N, d_max)``."""
        if "neighbour_mask" not in self._cache:
            self._build_neighbour_arrays()
        return self._cache["neighbour_mask"]

    def _build_neighbour_arrays(self) -> None:
        m, n, d_max = self.period, self.n_agents, self.max_in_degree
        index = np.broadcast_to(np.arange(n)[None, :, None], (m, n, d_max)).copy()
        mask = np.zeros((m, n, d_max), dtype=bool)
        for g, e in enumerate(self.edges):
            receivers = e[:, 1]
            # Edges are sorted by receiver, so the slot is the rank within the receiver.
            starts = np.concatenate(([0], np.cumsum(self.in_degree[g])[:-1]))
            slot = np.arange(len(e)) - starts[receivers]
            index[g, receivers, slot] = e[:, 0]
            mask[g, receivers, slot] = True
        self._cache["neighbour_index"] = index
        self._cache["neighbour_mask"] = mask

    def adjacency(self, g: int = 0) -> sp.csr_array:
        """Adjacency ``A`` of graph ``g`` (``a_ij = 1`` iff i receives from j), sparse ``(N, N)``."""
        e = self.edges[g]
        return sp.csr_array((np.ones(len(e)), (e[:, 1], e[:, 0])), shape=(self.n_agents,) * 2)

    def laplacian(self, g: int = 0) -> sp.csr_array:
        """Laplacian ``L = D - A`` of graph ``g``, sparse ``(N, N)``."""
        return sp.diags_array(self.in_degree[g].astype(float)) - self.adjacency(g)

    def averaging_matrix(self, g: int = 0) -> sp.csr_array:
        """``W = I - (D + I)^{-1} L`` of graph ``g`` (row-stochastic, sparse ``(N, N)``).

        Row i puts weight ``1 / (d_i + 1)`` on agent i and on each in-neighbour; one
        interval of the paper's controller maps ``V(t_k)`` to ``W V(t_k)`` (eq. 17a).
        """
        inv = 1.0 / (self.in_degree[g] + 1.0)
        return sp.diags_array(inv) @ (self.adjacency(g) + sp.eye_array(self.n_agents, format="csr"))

    def union(self) -> sp.csr_array:
        """Adjacency of the union of the period's graphs (the joint graph), sparse."""
        return sum((self.adjacency(g) for g in range(self.period)), sp.csr_array((self.n_agents,) * 2))

    def period_product(self) -> np.ndarray:
        """Dense ordered product ``Pi = W_{m-1} ... W_1 W_0`` (Theorem 2), ``(N, N)``."""
        self._require_dense("period_product")
        product = np.eye(self.n_agents)
        for g in range(self.period):
            product = self.averaging_matrix(g).toarray() @ product
        return product

    def consensus_weights(self) -> np.ndarray:
        """``xi``: the left eigenvector of ``Pi`` for eigenvalue 1 with ``sum(xi) = 1``.

        For a fixed graph ``Pi = W``. Theorems 1-2 give the final values
        ``x*(t) = xi^T x(0) + t xi^T v(0)`` and ``v* = xi^T v(0)``. Shape ``(N,)``.
        """
        if "xi" not in self._cache:
            self._require_dense("consensus_weights")
            product = self.period_product()
            # xi spans the null space of (Pi^T - I): the right singular vector of the
            # smallest singular value, which is simple when the joint graph spans.
            _, _, vh = np.linalg.svd(product.T - np.eye(self.n_agents))
            xi = vh[-1]
            xi = xi / xi.sum()
            xi[np.abs(xi) < 1e-15] = 0.0
            self._cache["xi"] = xi
        return self._cache["xi"]

    def _require_dense(self, what: str) -> None:
        if self.n_agents > DENSE_LIMIT:
            raise ArgumentError(
                f"{what}: builds dense (N, N) matrices and is limited to N <= {DENSE_LIMIT}; "
                f"this topology has N = {self.n_agents}"
            )

    def describe(self) -> str:
        """One line for logs and tables."""
        sizes = ", ".join(str(len(e)) for e in self.edges)
        kind = "fixed" if self.period == 1 else f"switching, period {self.period}"
        return f"{self.name} (N={self.n_agents}, {kind}, edges per graph: {sizes})"


def unreachable_from_best_root(adjacency: sp.csr_array) -> tuple[int, np.ndarray]:
    """Pick a root candidate of a directed graph and list the nodes it cannot reach.

    ``adjacency[i, j] != 0`` means an edge ``j -> i`` (i receives from j). The graph has a
    directed spanning tree iff the returned array is empty. O(N + |E|).

    Returns:
        ``(root, unreachable)``: the root candidate (a node of a source strongly connected
        component, the one that reaches most nodes) and the sorted nodes it cannot reach.
    """
    n = adjacency.shape[0]
    forward = sp.csr_array(adjacency.T)  # forward[j, i] != 0: edge j -> i
    n_comp, labels = csgraph.connected_components(forward, directed=True, connection="strong")
    coo = forward.tocoo()
    crossing = labels[coo.row] != labels[coo.col]
    has_incoming = np.zeros(n_comp, dtype=bool)
    has_incoming[labels[coo.col[crossing]]] = True
    sources = np.flatnonzero(~has_incoming)
    roots = [int(np.flatnonzero(labels == comp)[0]) for comp in sources]
    if len(roots) == 1:
        return roots[0], np.zeros(0, dtype=np.int64)
    # Several source components: none reaches the others. Report the best of a few.
    best_root, best_unreached = roots[0], np.arange(n)
    for root in roots[:8]:
        reached = csgraph.breadth_first_order(forward, root, directed=True, return_predecessors=False)
        unreached = np.setdiff1d(np.arange(n), reached)
        if len(unreached) < len(best_unreached):
            best_root, best_unreached = root, unreached
    return best_root, best_unreached


def check_spanning_tree(topology: Topology, argument: str = "topology") -> None:
    """Raise ``ValueError`` naming the unreachable agents unless the joint graph spans.

    For a period this is Theorem 2's condition (the union of the m graphs has a directed
    spanning tree); for a fixed graph, Assumption 1.
    """
    if topology.n_agents == 1:
        return
    root, unreached = unreachable_from_best_root(topology.union())
    if len(unreached):
        shown = ", ".join(str(int(a)) for a in unreached[:20])
        more = f" and {len(unreached) - 20} more" if len(unreached) > 20 else ""
        joint = "the union of the graphs of the period" if topology.period > 1 else "the graph"
        raise ArgumentError(
            f"{argument}: {joint} has no directed spanning tree, so consensus is impossible: "
            f"the best root candidate, agent {root}, cannot reach agents [{shown}{more}] "
            "(edges (j, i) mean i receives from j)"
        )


def _edge_array(edges: Any, argument: str, position: str) -> np.ndarray:
    """One edge list as an ``(E, 2)`` int64 array of integer node indices of magnitude below ``MAX_AGENTS``."""
    expected = "a sequence of (j, i) pairs of integer node indices"
    if isinstance(edges, str | bytes) or edges is None:
        raise ArgumentTypeError(f"{argument}: {position} must be {expected}, got {edges!r}")
    try:
        array = np.asarray(edges)
    except (TypeError, ValueError) as exc:
        raise ArgumentTypeError(f"{argument}: {position} must be {expected}") from exc
    if array.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if array.dtype.kind not in "biuf":
        raise ArgumentTypeError(f"{argument}: {position} must be {expected}, got entries of dtype {array.dtype}")
    if array.ndim != 2 or array.shape[1] != 2:
        raise ArgumentError(f"{argument}: {position} must be {expected}, got an array of shape {array.shape}")
    array = array.astype(np.float64)
    if not np.all(np.isfinite(array)) or not np.all(array == np.round(array)):
        raise ArgumentError(f"{argument}: {position} must contain integer node indices, got {_first_bad(array)!r}")
    huge = np.abs(array) >= validation.MAX_AGENTS
    if huge.any():
        raise ArgumentError(
            f"{argument}: {position} has node {array[huge][0]:g} outside 0..{validation.MAX_AGENTS - 1} "
            "(the most agents an episode takes)"
        )
    return array.astype(np.int64)


def _first_bad(array: np.ndarray) -> float:
    bad = ~np.isfinite(array) | (array != np.round(np.nan_to_num(array)))
    return float(array[bad][0])


def _normalise_edges(edges: Any, n_agents: int, argument: str, position: str) -> np.ndarray:
    """Validate one edge list and return it as a sorted ``(E, 2)`` int64 array."""
    array = _edge_array(edges, argument, position)
    if array.size == 0:
        return array
    bad = (array < 0) | (array >= n_agents)
    if bad.any():
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        raise ArgumentError(
            f"{argument}: {position} has edge {tuple(int(a) for a in array[row])} with a node "
            f"outside 0..{n_agents - 1} (n_agents = {n_agents})"
        )
    loops = array[:, 0] == array[:, 1]
    if loops.any():
        node = int(array[loops][0, 0])
        raise ArgumentError(f"{argument}: {position} has a self-loop ({node}, {node}); self-loops are not allowed")
    keys = array[:, 1] * n_agents + array[:, 0]
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    duplicate = np.flatnonzero(keys[1:] == keys[:-1])
    if len(duplicate):
        row = array[order][duplicate[0]]
        raise ArgumentError(f"{argument}: {position} lists edge ({int(row[0])}, {int(row[1])}) more than once")
    return np.ascontiguousarray(array[order])


def _digraph_nodes(graph: Any, argument: str, position: str) -> list[int]:
    """The node labels of a networkx DiGraph, which must be integers ``0..N-1``."""
    nodes = list(graph.nodes())
    for node in nodes:
        if isinstance(node, bool | np.bool_) or not isinstance(node, int | np.integer):
            raise ArgumentTypeError(
                f"{argument}: {position} is a networkx graph whose node labels must be the integers 0..N-1, got {node!r}"
            )
    return [int(node) for node in nodes]


def _digraph_edges(graph: Any, argument: str, position: str) -> list[tuple[int, int]]:
    _digraph_nodes(graph, argument, position)
    for u, v, weight in graph.edges(data="weight", default=1):
        # The paper's graphs are unweighted (a_ij = 1 on every edge): a weight would be dropped silently.
        if isinstance(weight, bool | np.bool_) or not isinstance(weight, int | float | np.number) or weight != 1:
            raise ArgumentError(
                f"{argument}: expected an unweighted networkx graph (the paper's graphs are unweighted: no "
                f"'weight' attribute, or weight 1); {position} has edge ({u}, {v}) with weight {weight!r}"
            )
    return [(int(u), int(v)) for u, v in graph.edges()]


def _is_digraph(obj: Any) -> bool:
    return hasattr(obj, "edges") and hasattr(obj, "is_directed") and callable(obj.edges)


def _is_edge_list_period(spec: Sequence[Any]) -> bool:
    """A period is a sequence of graphs; a single edge list is a sequence of pairs."""
    first = spec[0]
    if _is_digraph(first):
        return True
    if isinstance(first, np.ndarray):
        return first.ndim == 2 or first.size == 0
    return isinstance(first, Sequence) and (len(first) == 0 or isinstance(first[0], Sequence | np.ndarray))


def _infer_n_agents(graphs: Iterable[Any], positions: Iterable[str]) -> int:
    largest = -1
    for graph, position in zip(graphs, positions, strict=True):
        if _is_digraph(graph):
            largest = max(largest, max(_digraph_nodes(graph, "topology", position), default=-1))
        else:
            array = _edge_array(graph, "topology", position)
            largest = max(largest, int(array.max()) if array.size else -1)
    if largest < 0:
        raise ArgumentError("n_agents: cannot be inferred from a topology without edges; pass n_agents")
    return largest + 1


def make_topology(
    topology: Any = "paper_fig1",
    n_agents: int | None = None,
    *,
    seed: int | None = 0,
    mean_in_degree: float = 2.0,
    period: int = 1,
    check: bool = True,
) -> Topology:
    """Build a :class:`Topology` from a name, an edge list, a period of edge lists, or DiGraphs.

    Args:
        topology: a name from :data:`TOPOLOGY_NAMES`, one edge list of ``(j, i)`` pairs,
            a list of edge lists (one switching period), a networkx ``DiGraph`` (an edge
            ``u -> v`` means v receives from u), a list of DiGraphs, or a ``Topology``.
        n_agents: N. Defaults to 6 for names and to the largest node + 1 otherwise.
        seed: seed of the ``random`` generator.
        mean_in_degree: mean in-degree of the union graph for ``random``.
        period: number of graphs the ``random`` union is split into (switching when > 1).
        check: verify the (joint) directed spanning tree condition.

    Raises:
        ValueError / TypeError naming ``topology`` or ``n_agents`` for malformed input.
    """
    if n_agents is not None:
        n_agents = validation.integer("n_agents", n_agents, 1, validation.MAX_AGENTS)
    seed = validation.optional_seed("topology_seed", seed)
    if isinstance(topology, Topology):
        if n_agents is not None and n_agents != topology.n_agents:
            raise ArgumentError(f"n_agents: {n_agents} disagrees with the given Topology's {topology.n_agents} agents")
        result = topology
    elif isinstance(topology, str):
        result = named_topology(
            topology, 6 if n_agents is None else n_agents, seed=seed, mean_in_degree=mean_in_degree, period=period
        )
    else:
        if _is_digraph(topology):
            graphs: list[Any] = [topology]
        elif isinstance(topology, Sequence | np.ndarray) and len(topology) > 0 and _is_edge_list_period(topology):
            graphs = list(topology)
        elif isinstance(topology, Sequence | np.ndarray):
            graphs = [topology]
        else:
            raise ArgumentTypeError(
                f"topology: expected a name {TOPOLOGY_NAMES}, an edge list, a list of edge lists, "
                f"or networkx DiGraph(s); got {type(topology).__name__}"
            )
        for graph in graphs:
            if _is_digraph(graph) and not graph.is_directed():
                raise ArgumentError("topology: networkx graphs must be directed (DiGraph); got an undirected Graph")
        positions = [f"graph {g}" if len(graphs) > 1 else "the edge list" for g in range(len(graphs))]
        n = _infer_n_agents(graphs, positions) if n_agents is None else n_agents
        edges = []
        for graph, position in zip(graphs, positions, strict=True):
            raw = _digraph_edges(graph, "topology", position) if _is_digraph(graph) else graph
            edges.append(_normalise_edges(raw, n, "topology", position))
        result = Topology(n_agents=n, edges=tuple(edges))
    if check:
        check_spanning_tree(result)
    return result


def named_topology(
    name: str, n_agents: int = 6, *, seed: int | None = 0, mean_in_degree: float = 2.0, period: int = 1
) -> Topology:
    """The built-in generators; see :data:`TOPOLOGY_NAMES`.

    - ``ring``, ``path``, ``star``, ``complete``: :func:`structured_edges`.
    - ``random``: a uniformly random directed spanning tree plus random extra edges up to
      ``mean_in_degree``; with ``period > 1`` the edges are dealt at random to the m graphs,
      so only their union is guaranteed to span. O(N + |E|).
    - ``paper_fig1``: the **assumed** Fig. 1 of the paper (the image is lost): the ring
      1->2->...->6->1 split into ``G_0 = {1->2, 4->5}``, ``G_1 = {2->3, 5->6}``,
      ``G_2 = {3->4, 6->1}`` (1-based). No graph alone spans; the union does.
    """
    if name not in TOPOLOGY_NAMES:
        raise ArgumentError(f"topology: unknown name {name!r}; expected one of {TOPOLOGY_NAMES}")
    kind = GRAPH_KINDS[name]
    if kind.period_edges is not None:  # a fixed graph, given edge by edge
        if n_agents != kind.n_agents:
            raise ArgumentError(f"n_agents: topology {name!r} has {kind.n_agents} agents, got n_agents = {n_agents}")
        edges = tuple(_normalise_edges(e, n_agents, "topology", f"graph {g}") for g, e in enumerate(kind.period_edges))
        return Topology(n_agents=n_agents, edges=edges, name=name, note=kind.note)
    if kind.edges is None:  # drawn
        return random_topology(n_agents, seed=seed, mean_in_degree=mean_in_degree, period=period)
    edges = (_normalise_edges(structured_edges(name, n_agents), n_agents, "topology", "the edge list"),)
    return Topology(n_agents=n_agents, edges=edges, name=name)


def structured_edges(kind: str, n: int) -> np.ndarray:
    """The ``(sender, receiver)`` pairs of a structured kind of :data:`GRAPH_KINDS` on ``n`` agents.

    The one definition of the structured graphs, for fixed topologies (:func:`named_topology`)
    and topology families (:mod:`fxc_env.core.families`, which relabel the agents at random).
    """
    return np.zeros((0, 2), dtype=np.int64) if n == 1 else GRAPH_KINDS[kind].edges(np.arange(n))


def random_topology(n_agents: int, *, seed: int | None = 0, mean_in_degree: float = 2.0, period: int = 1) -> Topology:
    """Seeded random digraph(s) whose union has a directed spanning tree; O(N + |E|).

    A random order of the agents is drawn and each agent but the first receives from one
    uniformly chosen earlier agent (a random spanning tree). Every agent's in-degree is
    then raised to ``floor(mean_in_degree)`` or ``ceil(mean_in_degree)`` (at random, so the
    mean is ``mean_in_degree``; never below the tree's, never above N - 1) with senders
    drawn uniformly without repeats. Near-equal in-degrees keep the padded observation
    (its width is the largest in-degree) small at any N. With ``period = m > 1`` every edge
    goes to one of the m graphs at random, so only their union is sure to span.
    """
    mean_in_degree = validation.real("mean_in_degree", mean_in_degree, 0.0)
    period = validation.integer("topology_period", period, 1, validation.MAX_PERIOD)
    rng = np.random.default_rng(seed)
    n = n_agents
    order = rng.permutation(n)
    parents = order[(rng.random(n - 1) * np.arange(1, n)).astype(np.int64)]
    keys = np.sort(order[1:] * n + parents)  # key = receiver * N + sender, kept sorted
    base = np.floor(mean_in_degree)
    degree = np.minimum(base + (rng.random(n) < mean_in_degree - base), n - 1).astype(np.int64)
    missing = np.maximum(degree - np.bincount(keys // n, minlength=n), 0)
    while missing.any():
        receivers = np.repeat(np.arange(n), missing)
        senders = rng.integers(0, n - 1, size=len(receivers))
        senders += senders >= receivers  # uniform over the other agents
        fresh = np.sort(receivers * n + senders)
        fresh = fresh[np.concatenate(([True], fresh[1:] != fresh[:-1]))]
        at = np.minimum(np.searchsorted(keys, fresh), len(keys) - 1)
        fresh = fresh[keys[at] != fresh] if len(keys) else fresh
        # Keep at most `missing` new senders per receiver (the first in key order).
        rank = np.arange(len(fresh)) - np.searchsorted(fresh // n, fresh // n)
        fresh = fresh[rank < missing[fresh // n]]
        keys = np.sort(np.concatenate([keys, fresh]))
        missing = np.maximum(degree - np.bincount(keys // n, minlength=n), 0)
    pairs = np.stack([keys % n, keys // n], axis=1)
    graph_of_edge = rng.integers(0, period, size=len(pairs))
    edges = tuple(_normalise_edges(pairs[graph_of_edge == g], n, "topology", f"graph {g}") for g in range(period))
    label = "random" if period == 1 else f"random (switching, period {period})"
    return Topology(n_agents=n, edges=edges, name=label, note=f"seed {seed}, mean in-degree {mean_in_degree}")
