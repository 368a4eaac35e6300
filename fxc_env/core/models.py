"""The named agent models and the ``agent_model`` spec (docs: agent-models.md, "Agent models and formations").

Every agent obeys, per space axis, ``z' = A z + B u``. :func:`model_matrices` gives ``(A, B)``
of a named model; :func:`model_spec` reads the environment's ``agent_model`` argument: a
name, a dict ``{"name": ..., <parameter>: value}`` (``agent_model={"name": "damped",
"damping": 0.5}``) or a pair ``(A, B)``. The flat ``order``, ``damping`` and ``frequency``
arguments of the previous release still work for one release, with a
:class:`DeprecationWarning` naming the new spelling.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fxc_env.core import validation
from fxc_env.core.validation import ArgumentError

MODEL_NAMES = ("double_integrator", "single_integrator", "integrator_chain", "damped", "oscillator")
#: Orders accepted by the ``"integrator_chain"`` model.
CHAIN_ORDERS = (1, 2, 3, 4)
#: Default damping ``c`` of the ``"damped"`` model (1/s): ``v' = -c v + u``.
DEFAULT_DAMPING = 0.5
#: Default angular frequency ``omega`` of the ``"oscillator"`` model (rad/s): ``v' = -omega^2 x + u``.
DEFAULT_FREQUENCY = 1.0
#: The parameter each named model takes (a key of its spec beside ``"name"``); the others take none.
MODEL_PARAMETERS = {"integrator_chain": "order", "damped": "damping", "oscillator": "frequency"}
#: The previous release's flat arguments (deprecated): each one model's parameter.
FLAT_PARAMETERS = ("order", "damping", "frequency")


def model_matrices(
    name: Any, order: Any = None, damping: Any = None, frequency: Any = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of a named per-axis model, float64 ``(n, n)`` and ``(n, 1)``; states ``(x, v, ...)``.

    Args:
        name: one of :data:`MODEL_NAMES`:

            - ``"single_integrator"``: ``x' = u`` (n = 1).
            - ``"double_integrator"``: ``x' = v``, ``v' = u`` (n = 2, the paper's agent).
            - ``"integrator_chain"``: ``z_0' = z_1``, ..., ``z_{n-1}' = u`` with n = ``order``
              in 1..4 (default 2).
            - ``"damped"``: ``x' = v``, ``v' = -c v + u`` with c = ``damping`` >= 0 in 1/s (default 0.5).
            - ``"oscillator"``: ``x' = v``, ``v' = -omega^2 x + u`` with omega = ``frequency`` >= 0
              in rad/s (default 1).
        order, damping, frequency: the parameter of the model that has it; ``None`` for the default.

    Raises:
        ArgumentError naming ``agent_model`` (unknown name) or the parameter (out of range, or
        given to a model that has no such parameter).
    """
    name = validation.choice("agent_model", name, MODEL_NAMES)
    for parameter, value in (("order", order), ("damping", damping), ("frequency", frequency)):
        owner = next(model for model, key in MODEL_PARAMETERS.items() if key == parameter)
        if value is not None and owner != name:
            raise ArgumentError(
                f"{parameter}: only agent_model = {owner!r} has a {parameter}, "
                f"got {parameter} = {value!r} with agent_model = {name!r}"
            )
    if name == "single_integrator":
        return np.zeros((1, 1)), np.ones((1, 1))
    if name in ("double_integrator", "integrator_chain"):
        n = 2 if order is None else validation.integer("order", order, CHAIN_ORDERS[0], CHAIN_ORDERS[-1])
        return _chain(n)
    A, B = _chain(2)
    if name == "damped":
        A[1, 1] = -(DEFAULT_DAMPING if damping is None else validation.real("damping", damping, minimum=0.0))
    else:
        omega = DEFAULT_FREQUENCY if frequency is None else validation.real("frequency", frequency, minimum=0.0)
        A[1, 0] = -(omega * omega)
    return A, B


def _chain(n: int) -> tuple[np.ndarray, np.ndarray]:
    A = np.eye(n, k=1)
    B = np.zeros((n, 1))
    B[-1, 0] = 1.0
    return A, B


def model_spec(value: Any, flat: Mapping[str, Any] | None = None) -> tuple[str, dict[str, Any]]:
    """``agent_model`` as ``(name, parameters)``: the one reader of the spec, for every front end.

    ``value`` is None (the double integrator), a name of :data:`MODEL_NAMES`, a dict
    ``{"name": name, <its parameter>: value}`` or a pair ``(A, B)`` (name ``"linear"``,
    parameters ``{"A": A, "B": B}``). ``flat`` holds the deprecated ``order`` / ``damping`` /
    ``frequency`` arguments (None: not given); each one given warns with the new spelling and
    joins the spec. Parameter values are checked by :func:`model_matrices`.

    Raises:
        ArgumentError naming ``agent_model`` (a spec of the wrong form, an unknown name or key)
        or the flat parameter (given twice, or to a model without it).
    """
    given = {key: item for key, item in (flat or {}).items() if item is not None}
    if isinstance(value, tuple | list) and len(value) == 2 and not isinstance(value, str):
        for key in given:
            raise ArgumentError(f"{key}: a given (A, B) takes no {key}")
        return "linear", {"A": value[0], "B": value[1]}
    name, parameters = _named_spec(value)
    for key, item in given.items():
        validation.deprecated(
            f"{key}={item!r} is deprecated and goes away in the next release: write "
            f"agent_model={{'name': {name!r}, {key!r}: {item!r}}}"
        )
        if key in parameters:
            raise ArgumentError(f"{key}: given twice, flat and inside agent_model; give it inside agent_model only")
        if name == "double_integrator":
            raise ArgumentError(f"{key}: the double integrator takes no {key}; give agent_model too")
    return name, {**parameters, **given}


def _named_spec(value: Any) -> tuple[str, dict[str, Any]]:
    """A name or a ``{"name": ..., parameter: value}`` dict as ``(name, parameters)`` (keys checked)."""
    if value is None:
        return "double_integrator", {}
    if isinstance(value, str):
        return validation.choice("agent_model", value, MODEL_NAMES), {}
    if not isinstance(value, Mapping):
        raise ArgumentError(
            "agent_model: expected a model name, a dict {'name': name, <parameter>: value} or a pair (A, B), "
            f"got {type(value).__name__}"
        )
    if "name" not in value:
        raise ArgumentError(f"agent_model: expected a dict with a 'name' key, got the keys {sorted(map(str, value))}")
    name = validation.choice("agent_model['name']", value["name"], MODEL_NAMES)
    parameters = {key: item for key, item in value.items() if key != "name"}
    allowed = MODEL_PARAMETERS.get(name)
    unknown = sorted(str(key) for key in parameters if key != allowed)
    if unknown:
        takes = f"only {allowed!r}" if allowed else "no parameters"
        raise ArgumentError(f"agent_model: {name!r} takes {takes}, got the key(s) {unknown}")
    return name, parameters
