"""The training domain of a saved policy, and the check that an environment lies inside it.

Every policy file records its training domain (:func:`training_domain`, plain JSON,
:data:`DOMAIN_FORMAT`: graphs, N, switching, schedule, K, ``T_s``, limits, noise, dropout), and
every loader refuses an environment outside it, naming each difference, unless the user passes
``allow_out_of_domain=True`` (then an :class:`OutOfDomainWarning`; :func:`check_domain`). The
record's fields and what lies inside: docs: training.md, "The training domain".
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fxc_env.config import config_of
from fxc_env.core import graph_kinds
from fxc_env.core.families import TopologyMixture, edge_lists
from fxc_env.core.validation import ArgumentError, boolean

#: The ``format`` entry of a domain record.
DOMAIN_FORMAT = "fxc_env.policy_domain/1"
#: Range fields: ``[lo, hi]`` in the record, the environment's value must lie inside.
RANGE_FIELDS = ("n_agents", "n_intervals", "settling_time", "u_max", "obs_noise", "link_dropout")
#: The keyword of :func:`fxc_env.make_config` behind each field, for messages.
FIELD_KEYWORDS = {
    "graphs": "topology",
    "n_agents": "n_agents",
    "switching": "switching",
    "schedule": "schedule",
    "n_intervals": "n_intervals",
    "settling_time": "settling_time",
    "u_max": "u_max",
    "obs_noise": "obs_noise",
    "link_dropout": "link_dropout",
}
#: How a loader is told to run a policy outside its domain anyway.
ALLOW_HINT = "pass allow_out_of_domain=True (fxc: --allow-out-of-domain) to run it there anyway, with a warning"


class OutOfDomainWarning(UserWarning):
    """A policy runs outside its recorded training domain (``allow_out_of_domain=True``), or an exact extrapolation."""


# ------------------------------------------------------------------------------------ recording
def training_domain(config: Any, *more: Any) -> dict[str, Any]:
    """The training domain (see the module) of a policy trained on ``config`` (and ``more`` configs).

    Each is an EnvConfig or an fxc_env environment. Several configs (a policy trained on several
    settings) give the union: the graphs of all, the smallest ranges holding every value.
    """
    configs = [config_of(c, "training_domain") for c in (config, *more)]
    graphs: list[dict[str, Any]] = []
    for c in configs:
        for entry in _graph_entries(c):
            if entry not in graphs:
                graphs.append(entry)

    def span(values: list[float | None]) -> list[float] | None:
        known = [v for v in values if v is not None]
        return None if not known else [min(known), max(known)]

    def limits(c: Any) -> list[float | None]:
        return [None] if c.u_max_choices is None else [float(u) for u in c.u_max_choices]

    return {
        "format": DOMAIN_FORMAT,
        "graphs": graphs,
        "n_agents": span([int(c.n_agents) for c in configs]),
        "switching": sorted({c.switching for c in configs}),
        "schedule": sorted({c.schedule.name for c in configs}),
        "n_intervals": span([int(c.n_intervals) for c in configs]),
        "settling_time": span([float(c.settling_time) for c in configs]),
        "u_max": span([u for c in configs for u in limits(c)]),
        "obs_noise": span([float(c.obs_noise) for c in configs]),
        "link_dropout": span([float(c.link_dropout) for c in configs]),
        "dim": sorted({int(c.dim) for c in configs}),
        "action_mode": sorted({c.action_mode for c in configs}),
        "obs_mode": sorted({c.obs_mode for c in configs}),
        "agent_model": sorted({c.agent_model for c in configs}),
    }


def domain_from_settings(settings: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """The part of a domain that a file without one still records in its training settings.

    (:func:`fxc_env.policies.policy_files.training_settings`: N, K, T_s, schedule and the input
    limits; its graphs are not recorded, so they are not checked.) None without settings.
    """
    if not settings:
        return None
    u_max = settings.get("u_max")
    domain: dict[str, Any] = {"format": DOMAIN_FORMAT, "partial": True}
    for key in ("n_agents", "n_intervals", "settling_time"):
        if settings.get(key) is not None:
            domain[key] = [settings[key], settings[key]]
    if settings.get("schedule") is not None:
        domain["schedule"] = [settings["schedule"]]
    if "u_max" in settings:
        domain["u_max"] = None if not u_max else [min(u_max), max(u_max)]
    return domain


def _graph_entries(config: Any) -> list[dict[str, Any]]:
    family = config.family
    if family is None:
        topology = config.topology
        return [{"topology": topology.name, "edges": edge_lists(topology)}]
    members = family.families if isinstance(family, TopologyMixture) else (family,)
    return [_family_entry(member) for member in members]


# ------------------------------------------------------------------------------------- checking
def domain_differences(domain: Mapping[str, Any] | None, config: Any) -> list[tuple[str, str, str, bool]]:
    """``(field, trained, this environment, exact)`` for every way ``config`` lies outside ``domain``.

    ``exact`` marks an extrapolation that is exact by construction (docs: training.md, "The training domain"): it warns
    but is not refused. A missing field (or a None domain) checks nothing.
    """
    if not domain:
        return []
    c = config_of(config, "policy")
    found: list[tuple[str, str, str, bool]] = []
    here: dict[str, Any] = {
        "n_agents": [int(c.n_agents)],
        "n_intervals": [int(c.n_intervals)],
        "settling_time": [float(c.settling_time)],
        "u_max": None if c.u_max_choices is None else [float(u) for u in c.u_max_choices],
        "obs_noise": [float(c.obs_noise)],
        "link_dropout": [float(c.link_dropout)],
    }
    for key in RANGE_FIELDS:
        if key not in domain:
            continue
        trained, values = domain[key], here[key]
        if trained is None or values is None:
            if (trained is None) != (values is None) and key != "u_max":
                found.append((key, _range_text(trained), _values_text(values), False))
            continue  # u_max: the limit feature itself is an interface setting, checked elsewhere
        low, high = trained
        if any(not (low <= v <= high) for v in values):
            exact = key == "settling_time" and _time_rescales(c)
            found.append((key, _range_text(trained), _values_text(values), exact))
    for key, value in (("schedule", c.schedule.name), ("switching", c.switching)):
        if key not in domain or (key == "switching" and not _switches(c)):
            continue  # random switching among one graph is no switching
        if value not in domain[key]:
            found.append((key, " or ".join(repr(v) for v in domain[key]), repr(value), False))
    graphs = domain.get("graphs")
    if graphs:
        missing = _uncovered_graphs(graphs, c)
        if missing:
            trained = "; ".join(graph_label(g) for g in graphs)
            found.append(("graphs", trained, missing, False))
    return found


def describe_domain_differences(differences: Sequence[tuple[str, str, str, bool]]) -> str:
    """``"n_agents: trained on 20, this environment has 6; ..."``."""
    return "; ".join(
        f"{key}: trained on {trained}, this environment has {here}{' (exact by construction)' if exact else ''}"
        for key, trained, here, exact in differences
    )


def check_domain(
    domain: Mapping[str, Any] | None,
    config: Any,
    source: Any,
    allow_out_of_domain: bool = False,
    *,
    stacklevel: int = 3,
) -> list[tuple[str, str, str, bool]]:
    """Refuse an environment outside ``domain``, naming every difference; or warn, and return them.

    Raises :class:`ArgumentError` naming ``policy``, the file and every difference (field,
    training range and this environment's value) unless ``allow_out_of_domain`` or every
    difference is exact by construction; then warns (:class:`OutOfDomainWarning`) naming them. A
    policy that records no domain (``None``) also warns: nothing can be checked.
    """
    checked_allow(allow_out_of_domain)
    if domain is None:  # a file from before domains were recorded: say that nothing is checked
        warnings.warn(
            f"policy: {source} records no training domain, so nothing checks that this environment is one it "
            "was trained on (retrain it, or save it with this release to record one)",
            OutOfDomainWarning,
            stacklevel=stacklevel,
        )
        return []
    differences = domain_differences(domain, config)
    if not differences:
        return differences
    text = describe_domain_differences(differences)
    if not allow_out_of_domain and not all(exact for *_, exact in differences):
        keywords = sorted({FIELD_KEYWORDS[key] for key, *_ in differences})
        raise ArgumentError(
            f"policy: the model at {source} was trained on another domain than this environment: {text} "
            f"(make the environment match: {', '.join(keywords)}; or {ALLOW_HINT})"
        )
    label = "outside its training domain" if not all(e for *_, e in differences) else "beyond its training domain"
    warnings.warn(f"policy: {source} runs {label}: {text}", OutOfDomainWarning, stacklevel=stacklevel)
    return differences


def checked_allow(value: Any) -> bool:
    """``allow_out_of_domain`` once it is True or False; else the error naming it."""
    return boolean("allow_out_of_domain", value)


def _time_rescales(config: Any) -> bool:
    """Whether another ``T_s`` rescales away exactly (double integrator, normalized units, no input limit)."""
    return (
        config.agent_model == "double_integrator" and config.obs_mode == "normalized" and config.u_max_choices is None
    )


def _switches(config: Any) -> bool:
    """Whether the environment's graph can change from interval to interval."""
    if config.family is None:
        return config.topology.period > 1
    members = config.family.families if isinstance(config.family, TopologyMixture) else (config.family,)
    return any(m.period[1] > 1 for m in members)


def _range_text(pair: Any) -> str:
    if pair is None:
        return "none"
    low, high = pair
    return f"{low:g}" if low == high else f"{low:g} to {high:g}"


def _values_text(values: Any) -> str:
    if values is None:
        return "none"
    return ", ".join(f"{v:g}" for v in sorted(set(values)))


def graph_label(entry: Mapping[str, Any]) -> str:
    """A graph entry as text: ``"ring (period 1 to 4)"``, ``"random (mean in-degree 1.5 to 3, period 1)"``."""
    if "family" in entry:
        degree = f"mean in-degree {_range_text(entry['mean_in_degree'])}, " if "mean_in_degree" in entry else ""
        return f"{entry['family']} ({degree}period {_range_text(entry['period'])})"
    return f"the fixed topology {entry.get('topology')!r} ({len(entry.get('edges', []))} graph(s))"


# ------------------------------------------------------------------------------ graph coverage
def _uncovered_graphs(graphs: Sequence[Mapping[str, Any]], config: Any) -> str:
    """What of the environment's graphs no trained entry covers, as text ('' when all are covered)."""
    if config.family is None:
        topology = config.topology
        if any(_covers_fixed(entry, topology) for entry in graphs):
            return ""
        shape = union_kind(topology)
        return f"the fixed topology {topology.name!r} ({shape}, period {topology.period}, N = {topology.n_agents})"
    members = config.family.families if isinstance(config.family, TopologyMixture) else (config.family,)
    outside = [m for m in members if not any(_covers_family(entry, m) for entry in graphs)]
    return "; ".join(f"the family {graph_label(_family_entry(member))}" for member in outside) if outside else ""


def _family_entry(member: Any) -> dict[str, Any]:
    """A family's graph entry: its kind, period range and, for a kind that takes it, its mean in-degree range."""
    entry: dict[str, Any] = {"family": member.kind, "period": [int(p) for p in member.period]}
    if "mean_in_degree" in graph_kinds.FAMILY_KEYS[member.kind]:
        entry["mean_in_degree"] = [float(m) for m in member.mean_in_degree]
    return entry


def _inside(inner: Sequence[float], outer: Sequence[float]) -> bool:
    return outer[0] <= inner[0] and inner[1] <= outer[1]


def _covers_family(entry: Mapping[str, Any], member: Any) -> bool:
    if entry.get("family") != member.kind or not _inside(member.period, entry["period"]):
        return False
    return "mean_in_degree" not in entry or _inside(member.mean_in_degree, entry["mean_in_degree"])


def _covers_fixed(entry: Mapping[str, Any], topology: Any) -> bool:
    if "family" not in entry:
        recorded = entry.get("edges")
        return recorded is not None and _same_edges(recorded, topology)
    if not (entry["period"][0] <= topology.period <= entry["period"][1]):
        return False
    if "mean_in_degree" in entry:  # a drawn kind (random): its in-degrees
        return _random_draw(topology, *entry["mean_in_degree"])
    return union_kind(topology) == entry["family"]


def _same_edges(recorded: Sequence[Any], topology: Any) -> bool:
    return len(recorded) == topology.period and all(
        {tuple(p) for p in np.asarray(graph, dtype=np.int64).reshape(-1, 2).tolist()}
        == {tuple(p) for p in np.asarray(edges).tolist()}
        for graph, edges in zip(recorded, topology.edges, strict=True)
    )


def _union(topology: Any) -> tuple[np.ndarray, np.ndarray, int]:
    """In- and out-degrees of the union graph (the set of every graph's edges), and its edge count."""
    n = topology.n_agents
    keys = np.unique(np.concatenate([e[:, 0] * n + e[:, 1] for e in topology.edges]) if topology.edges else [])
    senders, receivers = keys // n, keys % n
    return np.bincount(receivers, minlength=n), np.bincount(senders, minlength=n), len(keys)


def union_kind(topology: Any) -> str:
    """``ring``, ``path``, ``star`` or ``complete`` when the union graph is one (in any labelling), else ``another graph``.

    The union spans (every environment's does), so a union with every in- and out-degree 1 is
    one directed cycle, one with N - 1 edges and in- and out-degrees at most 1 a directed path.
    """
    return graph_kinds.union_kind(*_union(topology))


def _random_draw(topology: Any, low: float, high: float) -> bool:
    """Whether the union could be a ``random`` family's draw for a mean in-degree in ``[low, high]``.

    A draw of mean in-degree ``m`` gives every agent ``floor(m)`` or ``ceil(m)`` in-neighbours
    (:func:`fxc_env.core.graphs.random_topology`; at most N - 1, at least the spanning tree's 1).
    """
    n = topology.n_agents
    indeg, _, _ = _union(topology)
    top = min(math.ceil(high), n - 1)
    smallest, largest = int(indeg.min()), int(indeg.max())
    if largest - smallest > 1 or largest > top:
        return False
    if smallest == largest:  # some m in (d - 1, d + 1), or any m >= N - 1 when capped
        lower, upper = smallest - 1, (math.inf if smallest == n - 1 else smallest + 1)
        return low < upper and high > lower
    return low < largest and high > smallest  # mixed d and d + 1: m strictly between
