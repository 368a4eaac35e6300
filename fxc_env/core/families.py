"""Topology families: a distribution over (switching) digraphs, drawn anew for every episode.

A :class:`TopologyFamily` draws a new graph set every episode, a :class:`TopologyMixture` first
picks a family by weight. Every draw satisfies the paper's condition (Theorem 1 for a fixed graph,
Theorem 2 for a period) because each family builds a spanning union graph first and only then
deals its edges to the ``m`` graphs of the period (the union graphs: docs: environment.md,
"Topology families"). Draws use only the generator passed in; :func:`edge_lists` turns a drawn
topology into plain lists that ``make_topology`` accepts back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.core import validation
from fxc_env.core.graph_kinds import FAMILY_KEYS, FAMILY_KINDS, GRAPH_KINDS
from fxc_env.core.graphs import Topology, make_topology, random_topology, structured_edges
from fxc_env.core.validation import ArgumentError


def _range(name: str, value: Any, kind: type, minimum: float) -> tuple[Any, Any]:
    """A number or a ``(low, high)`` pair, as a validated pair with ``low <= high``."""
    pair = tuple(value) if isinstance(value, Sequence) and not isinstance(value, str) else (value, value)
    if len(pair) != 2:
        raise ArgumentError(f"{name}: expected a number or a (low, high) pair, got {value!r}")
    if kind is int:
        low, high = (validation.integer(name, v, int(minimum), validation.MAX_PERIOD) for v in pair)
    else:
        low, high = (validation.real(name, v, minimum) for v in pair)
    if low > high:
        raise ArgumentError(f"{name}: expected low <= high, got {value!r}")
    return low, high


@dataclass(frozen=True)
class TopologyFamily:
    """One family of topologies (see the module table).

    Attributes:
        kind: one of :data:`FAMILY_KINDS`.
        mean_in_degree: ``(low, high)`` range of the ``random`` family's mean in-degree.
        period: ``(low, high)`` range of the switching period ``m`` (``(1, 1)``: fixed graphs).
        relabel: draw a random labelling of the agents (``ring``, ``path``, ``star``), so agent
            0 is not always the leader or the path's root.
    """

    kind: str
    mean_in_degree: tuple[float, float] = (2.0, 2.0)
    period: tuple[int, int] = (1, 1)
    relabel: bool = True

    @property
    def name(self) -> str:
        parts = [self.kind]
        if "mean_in_degree" in FAMILY_KEYS[self.kind]:
            low, high = self.mean_in_degree
            parts.append(f"d{low:g}" if low == high else f"d{low:g}-{high:g}")
        if self.period != (1, 1):
            low, high = self.period
            parts.append(f"m{low}" if low == high else f"m{low}-{high}")
        return "_".join(parts)

    def max_in_degree(self, n_agents: int) -> int:
        """The largest in-degree any draw on ``n_agents`` agents can have (the observation's slots)."""
        return 0 if n_agents == 1 else GRAPH_KINDS[self.kind].in_degree(n_agents, self.mean_in_degree[1])

    def draw(self, n_agents: int, rng: np.random.Generator) -> Topology:
        """One topology on ``n_agents`` agents whose (joint) graph spans."""
        period = int(rng.integers(self.period[0], self.period[1] + 1))
        if GRAPH_KINDS[self.kind].edges is None:  # drawn at random (random)
            low, high = self.mean_in_degree
            mean = low if low == high else float(rng.uniform(low, high))
            seed = int(rng.integers(0, 2**63))
            union = random_topology(n_agents, seed=seed, mean_in_degree=mean, period=1).edges[0]
        else:
            union = structured_edges(self.kind, n_agents)
            if self.relabel and n_agents > 1:
                union = rng.permutation(n_agents)[union]
        graph_of_edge = rng.integers(0, period, size=len(union))
        edges = [union[graph_of_edge == g] for g in range(period)]
        drawn = make_topology(edges if period > 1 else edges[0], n_agents, check=False)
        return Topology(n_agents, drawn.edges, name=self.name, note="drawn from a family")


@dataclass(frozen=True)
class TopologyMixture:
    """Families drawn with the given weights; then the chosen family draws the topology."""

    families: tuple[TopologyFamily, ...]
    weights: tuple[float, ...]
    label: str = "mixture"

    @property
    def name(self) -> str:
        return self.label

    def max_in_degree(self, n_agents: int) -> int:
        return max(family.max_in_degree(n_agents) for family in self.families)

    def draw(self, n_agents: int, rng: np.random.Generator) -> Topology:
        probabilities = np.asarray(self.weights) / math.fsum(self.weights)
        return self.families[int(rng.choice(len(self.families), p=probabilities))].draw(n_agents, rng)


AnyFamily = TopologyFamily | TopologyMixture


def make_family(spec: Any, argument: str = "topology") -> AnyFamily:
    """A family from its description.

    ``spec`` is a :class:`TopologyFamily` or :class:`TopologyMixture`, or a mapping:
    ``{"family": "random", "mean_in_degree": (1.5, 3.0), "period": (1, 3), "relabel": True}``
    (every key but ``family`` optional; :data:`FAMILY_KEYS` lists the keys each family uses), or
    ``{"mixture": [(family_spec, weight), ...], "name": "..."}``, where a member's ``family_spec``
    may also be a bare family name (``("random", 2.0)`` means ``({"family": "random"}, 2.0)``).
    """
    if isinstance(spec, TopologyFamily | TopologyMixture):
        return spec
    if not isinstance(spec, Mapping):
        raise ArgumentError(
            f"{argument}: expected a family mapping {{'family': ...}} or {{'mixture': ...}}, got {spec!r}"
        )
    if "mixture" in spec:
        unknown = set(spec) - {"mixture", "name"}
        if unknown:
            raise ArgumentError(
                f"{argument}: unknown key(s) {sorted(unknown)} in a mixture; expected 'mixture', 'name'"
            )
        members = spec["mixture"]
        if isinstance(members, str | bytes) or not isinstance(members, Sequence) or not members:
            raise ArgumentError(f"{argument}: 'mixture' must be a non-empty list of (family, weight) pairs")
        families, weights = [], []
        for member in members:
            if not isinstance(member, Sequence) or isinstance(member, str) or len(member) != 2:
                raise ArgumentError(f"{argument}: each mixture entry must be a (family, weight) pair, got {member!r}")
            # A bare name is the family with its defaults: ("random", 2.0) is ({"family": "random"}, 2.0).
            family = make_family({"family": member[0]} if isinstance(member[0], str) else member[0], argument)
            if isinstance(family, TopologyMixture):
                raise ArgumentError(f"{argument}: a mixture's members must be families, not mixtures")
            families.append(family)
            weights.append(
                validation.real(f"{argument} mixture weight", member[1], maximum=validation.STATE_LIMIT, positive=True)
            )
        name = spec.get("name", "mixture")
        if not isinstance(name, str):
            raise ArgumentError(f"{argument}: a mixture's 'name' must be a string, got {name!r}")
        return TopologyMixture(tuple(families), tuple(weights), name)
    unknown = set(spec) - {"family", "mean_in_degree", "period", "relabel"}
    if unknown:
        raise ArgumentError(
            f"{argument}: unknown key(s) {sorted(unknown)}; expected 'family', 'mean_in_degree', 'period', 'relabel'"
        )
    kind = validation.choice(f"{argument}['family']", spec.get("family"), FAMILY_KINDS)
    unused = [key for key in spec if key != "family" and key not in FAMILY_KEYS[kind]]
    if unused:
        takes = ", ".join(repr(key) for key in ("family", *FAMILY_KEYS[kind]))
        raise ArgumentError(f"{argument}: the {kind!r} family does not use {unused!r}; its keys are {takes}")
    relabel = spec.get("relabel", True)
    validation.boolean(f"{argument}['relabel']", relabel)
    return TopologyFamily(
        kind=kind,
        mean_in_degree=_range(f"{argument}['mean_in_degree']", spec.get("mean_in_degree", 2.0), float, 0.0),
        period=_range(f"{argument}['period']", spec.get("period", 1), int, 1),
        relabel=relabel,
    )


def is_family_spec(spec: Any) -> bool:
    """Whether ``spec`` describes a family (drawn per episode) rather than one topology."""
    return isinstance(spec, TopologyFamily | TopologyMixture) or (
        isinstance(spec, Mapping) and ("family" in spec or "mixture" in spec)
    )


def edge_lists(topology: Topology) -> list[list[list[int]]]:
    """The topology's graphs as plain lists of ``[j, i]`` pairs (``make_topology`` takes them back)."""
    return [edges.tolist() for edges in topology.edges]
