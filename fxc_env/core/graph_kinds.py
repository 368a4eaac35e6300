"""The built-in kinds of communication graph, one table: :data:`GRAPH_KINDS`.

Each kind is a fixed topology by its name (``topology="ring"``, :func:`fxc_env.core.graphs.named_topology`) and,
where it has ``family_keys``, a family drawn anew every episode (``topology={"family": "ring"}``,
:mod:`fxc_env.core.families`). The graph code, the families, the flags of ``fxc`` (``--family``), a policy file's
training-domain record (:mod:`fxc_env.policies.records`) and its coverage check (:mod:`fxc_env.policies.domain`)
read this table, so adding a kind is one entry here (docs: extending.md, "A graph family"). An edge
``(j, i)``: agent i receives from agent j (the paper's convention, :mod:`fxc_env.core.graphs`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GraphKind:
    """A built-in kind of graph.

    Attributes:
        edges: a structured kind's ``(sender, receiver)`` pairs ``(E, 2)`` on the agents ``nodes`` ``(N,)``, N >= 2;
            None for a kind drawn at random (``random``) or given edge by edge (``period_edges``).
        period_edges: a fixed graph's ``(j, i)`` pairs, one list per graph of its period, on ``n_agents`` agents.
        n_agents: the agents of a graph given edge by edge; ``note``: where it comes from.
        family_keys: the keys of its family mapping beside ``family``, or None (no family of this kind).
        in_degree: ``in_degree(n_agents, mean_in_degree_high)``, the largest in-degree one of its draws can have.
        is_union: ``is_union(in_degrees, out_degrees, n_edges)``, whether a spanning union graph with these
            degrees (each ``(N,)``) is this kind in some labelling; None: never recognised (a random draw's).
    """

    edges: Callable[[np.ndarray], np.ndarray] | None = None
    period_edges: tuple[tuple[tuple[int, int], ...], ...] | None = None
    n_agents: int | None = None
    note: str = ""
    family_keys: tuple[str, ...] | None = ("period", "relabel")
    in_degree: Callable[[int, float], int] = lambda n, _: 1
    is_union: Callable[[np.ndarray, np.ndarray, int], bool] | None = None


def _complete(nodes: np.ndarray) -> np.ndarray:
    senders, receivers = np.meshgrid(nodes, nodes, indexing="ij")
    off = senders != receivers
    return np.stack([senders[off], receivers[off]], axis=1)


#: Every built-in graph kind by name. ``paper_fig1`` is the **assumed** Fig. 1 of the paper (the image is lost): the
#: ring 1->2->...->6->1 split into ``G_0 = {1->2, 4->5}``, ``G_1 = {2->3, 5->6}``, ``G_2 = {3->4, 6->1}`` (1-based);
#: no graph alone spans, the union does. ``ring``: ``0 -> 1 -> ... -> N-1 -> 0``; ``path``: ``0 -> ... -> N-1``,
#: rooted at 0; ``star``: agent 0 sends to every other (a leader, ``xi = e_0``); ``complete`` is not relabelled (every
#: labelling is the same graph); ``random``: :func:`fxc_env.core.graphs.random_topology`.
GRAPH_KINDS: dict[str, GraphKind] = {
    "paper_fig1": GraphKind(
        period_edges=(((0, 1), (3, 4)), ((1, 2), (4, 5)), ((2, 3), (5, 0))),
        n_agents=6,
        note="assumed Fig. 1 (reconstruction; the paper's image is lost)",
        family_keys=None,
    ),
    "ring": GraphKind(
        edges=lambda nodes: np.stack([nodes, (nodes + 1) % len(nodes)], axis=1),
        # every in- and out-degree 1 in a spanning graph: one directed cycle (on two agents, the complete graph)
        is_union=lambda indeg, outdeg, count: bool(np.all(indeg == 1) and np.all(outdeg == 1)) and count > 2,
    ),
    "path": GraphKind(
        edges=lambda nodes: np.stack([nodes[:-1], nodes[1:]], axis=1),
        is_union=lambda indeg, outdeg, count: count == len(indeg) - 1 and indeg.max() <= 1 and outdeg.max() <= 1,
    ),
    "star": GraphKind(
        edges=lambda nodes: np.stack([np.zeros(len(nodes) - 1, np.int64), nodes[1:]], axis=1),
        is_union=lambda indeg, outdeg, count: count == len(indeg) - 1 and outdeg.max() == len(indeg) - 1,
    ),
    "complete": GraphKind(
        edges=_complete,
        family_keys=("period",),
        in_degree=lambda n, _: n - 1,
        is_union=lambda indeg, outdeg, count: count == len(indeg) * (len(indeg) - 1),
    ),
    "random": GraphKind(
        family_keys=("mean_in_degree", "period"), in_degree=lambda n, high: max(1, min(math.ceil(high), n - 1))
    ),
}
#: The names of fixed topologies, in :data:`GRAPH_KINDS`' order.
TOPOLOGY_NAMES = tuple(GRAPH_KINDS)
#: The kinds of topology family (:mod:`fxc_env.core.families`) and the keys of each one's mapping beside ``family``:
#: ``mean_in_degree`` shapes ``random`` only, and ``relabel`` the structured families whose labels matter.
FAMILY_KEYS: dict[str, tuple[str, ...]] = {name: k.family_keys for name, k in GRAPH_KINDS.items() if k.family_keys}
FAMILY_KINDS = tuple(FAMILY_KEYS)


def union_kind(in_degrees: np.ndarray, out_degrees: np.ndarray, n_edges: int) -> str:
    """The first kind of :data:`GRAPH_KINDS` whose graph a spanning union graph with these degrees (each ``(N,)``)
    and ``n_edges`` edges is, in any labelling, else ``another graph``."""
    if len(in_degrees) < 2:
        return "another graph"
    found = (name for name, k in GRAPH_KINDS.items() if k.is_union and k.is_union(in_degrees, out_degrees, n_edges))
    return next(found, "another graph")
