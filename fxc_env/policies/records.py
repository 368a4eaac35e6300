"""The checks every policy file's records pass on load, written once: the training domain and the numbers.

:func:`checked_domain` checks a training-domain record (:mod:`fxc_env.policies.domain`) against its
schema, :data:`DOMAIN_SCHEMA`: every field that :func:`~fxc_env.policies.domain.training_domain`
writes, each of the type and range it writes, no other; a file without a record (``None``) passes as
None, and its loader says that nothing is checked (an ``OutOfDomainWarning``). Every format calls it:
the SB3 ``.zip``'s ``fxc_policy.json``, a torch ``policy.pt``, a gain schedule's ``.npz`` header and an
RLlib checkpoint's ``fxc_policy.json``. :func:`file_number` and :func:`file_tensor` check the other
numbers of a policy file (sizes, ``action_bound``, ``log_std``, weights) with the
:mod:`fxc_env.core.validation` helpers. Each refusal is an :class:`ArgumentError` that names
``policy``, the file and the field. Docs: bad-input.md, "Saved policies are data".
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fxc_env.core.graph_kinds import FAMILY_KEYS, FAMILY_KINDS
from fxc_env.core.validation import (
    MAX_AGENTS,
    MAX_DIM,
    MAX_INTERVALS,
    MAX_PERIOD,
    MAX_SETTLING_TIME,
    MIN_AGENTS,
    STATE_LIMIT,
    ArgumentError,
    integer,
    real,
)
from fxc_env.core.validation import short_repr as _short
from fxc_env.policies.domain import DOMAIN_FORMAT

#: The range fields of a domain record: ``[low, high]`` with ``low <= high``, each ``(integral, minimum,
#: maximum, positive, may be None)``; ``u_max`` is None for a policy trained without input limits.
RANGE_SCHEMA: dict[str, tuple[bool, float, float, bool, bool]] = {
    "n_agents": (True, MIN_AGENTS, MAX_AGENTS, False, False),
    "n_intervals": (True, 1, MAX_INTERVALS, False, False),
    "settling_time": (False, 0.0, MAX_SETTLING_TIME, True, False),
    "u_max": (False, 0.0, STATE_LIMIT, True, True),
    "obs_noise": (False, 0.0, STATE_LIMIT, False, False),
    "link_dropout": (False, 0.0, 1.0, False, False),
}
#: The fields that list names (a non-empty list of strings).
NAME_FIELDS = ("switching", "schedule", "action_mode", "obs_mode", "agent_model")
#: Every field of a domain record besides ``format`` (:func:`checked_domain` requires each, and no other).
DOMAIN_SCHEMA = ("graphs", *RANGE_SCHEMA, *NAME_FIELDS, "dim")


def checked_domain(record: Any, source: Any) -> dict[str, Any] | None:
    """The training-domain ``record`` of the policy file ``source`` once it meets the schema (see the module).

    None (a file that records no domain) gives None. Anything else must be a mapping whose ``format`` is
    :data:`~fxc_env.policies.domain.DOMAIN_FORMAT` and which holds every field of :data:`DOMAIN_SCHEMA`,
    well formed, and no other; else an :class:`ArgumentError` names ``policy``, ``source`` and the field
    (``domain.n_agents``): ``{}``, ``False``, ``0`` or a record of its ``format`` alone would check nothing.
    """
    if record is None:
        return None
    where = f"policy: {source}: domain"
    if not isinstance(record, Mapping):
        raise ArgumentError(
            f"{where}: expected the training-domain record (a mapping of format {DOMAIN_FORMAT!r}) or none, "
            f"got {_short(record)}"
        )
    if record.get("format") != DOMAIN_FORMAT:
        raise ArgumentError(f"{where}.format: expected {DOMAIN_FORMAT!r}, got {_short(record.get('format'))}")
    missing = [key for key in DOMAIN_SCHEMA if key not in record]
    if missing:
        raise ArgumentError(
            f"{where}: the record lacks {', '.join(missing)} (a {DOMAIN_FORMAT!r} record holds "
            f"{', '.join(DOMAIN_SCHEMA)}; a partial one would leave them unchecked)"
        )
    unknown = sorted(str(key) for key in record if key != "format" and key not in DOMAIN_SCHEMA)
    if unknown:
        raise ArgumentError(f"{where}: unknown field(s) {', '.join(unknown)} in a {DOMAIN_FORMAT!r} record")
    for key, (integral, low, high, positive, nullable) in RANGE_SCHEMA.items():
        if not (nullable and record[key] is None):
            _check_range(f"{where}.{key}", record[key], integral, low, high, positive)
    for key in NAME_FIELDS:
        value = record[key]
        if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
            raise ArgumentError(f"{where}.{key}: expected a non-empty list of names, got {_short(value)}")
    if not isinstance(record["dim"], list) or not record["dim"]:
        raise ArgumentError(f"{where}.dim: expected a non-empty list of integers, got {_short(record['dim'])}")
    for value in record["dim"]:
        integer(f"{where}.dim", value, 1, MAX_DIM)
    graphs = record["graphs"]
    if not isinstance(graphs, list) or not graphs:
        raise ArgumentError(f"{where}.graphs: expected a non-empty list of graph entries, got {_short(graphs)}")
    for index, entry in enumerate(graphs):
        _check_graph(f"{where}.graphs[{index}]", entry)
    return dict(record)


def _check_range(name: str, value: Any, integral: bool, low: float, high: float, positive: bool = False) -> None:
    """Refuse ``value`` unless it is ``[a, b]``, ``a <= b``, each in ``[low, high]`` (``> 0`` with ``positive``)."""
    if not isinstance(value, list | tuple) or len(value) != 2:
        raise ArgumentError(f"{name}: expected [low, high], got {_short(value)}")
    if integral:
        first, second = (integer(name, v, int(low), int(high)) for v in value)
    else:
        first, second = (real(name, v, None if positive else low, high, positive=positive) for v in value)
    if first > second:
        raise ArgumentError(f"{name}: expected [low, high] with low <= high, got {_short(value)}")


def _check_graph(name: str, entry: Any) -> None:
    """Refuse a graph entry unless it is a family's (``family``, ``period``, ``mean_in_degree`` for
    ``random``) or a fixed topology's (``topology``, ``edges``: per graph, ``[j, i]`` pairs)."""
    if not isinstance(entry, Mapping):
        raise ArgumentError(f"{name}: expected a graph entry (a mapping), got {_short(entry)}")
    if "family" in entry:
        kind = entry["family"]
        if kind not in FAMILY_KINDS:
            raise ArgumentError(f"{name}.family: expected one of {FAMILY_KINDS}, got {_short(kind)}")
        keys = {"family", "period", *(("mean_in_degree",) if "mean_in_degree" in FAMILY_KEYS[kind] else ())}
        if set(entry) != keys:
            raise ArgumentError(f"{name}: a {kind!r} entry holds {sorted(keys)}, got {sorted(map(str, entry))}")
        _check_range(f"{name}.period", entry["period"], True, 1, MAX_PERIOD)
        if "mean_in_degree" in keys:
            _check_range(f"{name}.mean_in_degree", entry["mean_in_degree"], False, 0.0, MAX_AGENTS, True)
        return
    if set(entry) != {"topology", "edges"} or not isinstance(entry["topology"], str):
        raise ArgumentError(
            f"{name}: expected a family's entry (family, period) or a fixed topology's (topology: a name, edges), "
            f"got {_short(dict(entry))}"
        )
    edges = entry["edges"]
    if not isinstance(edges, list) or not edges or not 1 <= len(edges) <= MAX_PERIOD:
        raise ArgumentError(f"{name}.edges: expected one list of edges per graph, got {_short(edges)}")
    for graph in edges:
        if not isinstance(graph, list) or not all(_pair(pair) for pair in graph):
            raise ArgumentError(f"{name}.edges: expected [j, i] pairs of agent indices, got {_short(graph)}")


def _pair(pair: Any) -> bool:
    return isinstance(pair, list | tuple) and len(pair) == 2 and all(_index(v) for v in pair)


def _index(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool) and 0 <= value < MAX_AGENTS


def file_number(
    source: Any, field: str, value: Any, *, integral: bool = False, minimum: float | None = None, **limits: Any
) -> Any:
    """``value``, the ``field`` of the policy file ``source``, once it is a finite number (an ``int`` with
    ``integral``) in range (``minimum``; ``maximum``, ``positive`` as :func:`~fxc_env.core.validation.real`);
    else an :class:`ArgumentError` naming ``policy``, the file and the field."""
    name = f"policy: {source}: {field}"
    if integral:
        return integer(name, value, None if minimum is None else int(minimum), limits.get("maximum"))
    return real(name, value, minimum, limits.get("maximum"), positive=limits.get("positive", False))


def file_tensor(source: Any, field: str, value: Any, shape: tuple[int, ...] | None = None) -> Any:
    """``value`` (a torch tensor or array), the ``field`` of the policy file ``source``, once it has ``shape``
    (when given) and only finite entries; else an :class:`ArgumentError` naming ``policy``, the file and the field."""
    name = f"policy: {source}: {field}"
    found = tuple(getattr(value, "shape", ()))
    if not hasattr(value, "shape") or (shape is not None and found != tuple(shape)):
        expected = f"shape {tuple(shape)}" if shape is not None else "an array"
        raise ArgumentError(f"{name}: expected {expected}, got {_short(found if hasattr(value, 'shape') else value)}")
    try:
        array = np.asarray(value.detach().cpu().double() if hasattr(value, "detach") else value, dtype=np.float64)
    except (TypeError, ValueError, RuntimeError):
        raise ArgumentError(f"{name}: expected real numbers, got {_short(value)}") from None
    if not np.all(np.isfinite(array)):
        raise ArgumentError(f"{name}: every entry must be finite (no NaN or inf)")
    return value


def file_box(source: Any, field: str, record: Mapping[str, Any], *, bounded: bool) -> None:
    """Refuse a Box space's record (``shape``, ``low``, ``high``: the ``field`` of the policy file ``source``) unless
    ``shape`` holds integers >= 1 and ``low`` and ``high`` as many real numbers each, ``low <= high``
    (``low < high`` and finite within ±1e100 with ``bounded``: an action space, whose bounds clip every action);
    the :class:`ArgumentError` names ``policy``, the file and the field."""
    name = f"policy: {source}: {field}"
    shape = record["shape"]
    if not isinstance(shape, list | tuple) or not shape:
        raise ArgumentError(f"{name}.shape: expected a list of sizes, got {_short(shape)}")
    size = int(np.prod([integer(f"{name}.shape", n, 1) for n in shape]))
    bounds = []
    for key in ("low", "high"):
        try:
            values = np.asarray(record[key], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise ArgumentError(f"{name}.{key}: expected {size} real numbers, got {_short(record[key])}") from None
        if values.size != size or np.any(np.isnan(values)) or (bounded and not np.all(np.abs(values) <= STATE_LIMIT)):
            expected = f"{size} finite numbers within ±{STATE_LIMIT:g}" if bounded else f"{size} numbers (no NaN)"
            raise ArgumentError(f"{name}.{key}: expected {expected}, got {_short(record[key])}")
        bounds.append(values)
    if np.any(bounds[0] > bounds[1]) or (bounded and np.any(bounds[0] == bounds[1])):
        relation = "low < high" if bounded else "low <= high"
        raise ArgumentError(f"{name}: expected {relation} in every entry, got low {_short(record['low'])}")
