"""The named agent models and the ``agent_model`` spec (docs: agent-models.md, "Agent models and formations").

Every agent obeys, per space axis, ``z' = A z + B u``. :func:`model_matrices` gives ``(A, B)``
of a named model; :func:`model_spec` reads the environment's ``agent_model`` argument: a
name, a dict ``{"name": ..., <parameter>: value}`` (``agent_model={"name": "damped",
"damping": 0.5}``) or a pair ``(A, B)``. The flat ``order``, ``damping`` and ``frequency``
arguments of the previous release still work for one release, with a
:class:`DeprecationWarning` naming the new spelling.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.core import validation
from fxc_env.core.validation import ArgumentError

#: Orders accepted by the ``"integrator_chain"`` model.
CHAIN_ORDERS = (1, 2, 3, 4)
#: Default damping ``c`` of the ``"damped"`` model (1/s): ``v' = -c v + u``.
DEFAULT_DAMPING = 0.5
#: Default angular frequency ``omega`` of the ``"oscillator"`` model (rad/s): ``v' = -omega^2 x + u``.
DEFAULT_FREQUENCY = 1.0


@dataclass(frozen=True)
class AgentModel:
    """A named per-axis agent model ``z' = A z + B u``: one entry of :data:`AGENT_MODELS`.

    Attributes:
        matrices: ``matrices(value)``, its ``(A, B)`` (float64 ``(n, n)``, ``(n, 1)``) for its parameter's
            ``value`` (None: the default), the value checked there (an error naming the parameter).
        parameter: the name of its one parameter (a key of its spec beside ``"name"``, and an ``fxc`` flag), or None.
        flag_type, flag_help: the type and the help text of that flag (``--damping``).
    """

    matrices: Callable[[Any], tuple[np.ndarray, np.ndarray]]
    parameter: str | None = None
    flag_type: type = float
    flag_help: str = ""


def _chain(n: int) -> tuple[np.ndarray, np.ndarray]:
    A = np.eye(n, k=1)
    B = np.zeros((n, 1))
    B[-1, 0] = 1.0
    return A, B


def _damped(damping: Any) -> tuple[np.ndarray, np.ndarray]:
    A, B = _chain(2)
    A[1, 1] = -(DEFAULT_DAMPING if damping is None else validation.real("damping", damping, minimum=0.0))
    return A, B


def _oscillator(frequency: Any) -> tuple[np.ndarray, np.ndarray]:
    A, B = _chain(2)
    omega = DEFAULT_FREQUENCY if frequency is None else validation.real("frequency", frequency, minimum=0.0)
    A[1, 0] = -(omega * omega)
    return A, B


#: Every named agent model (docs: agent-models.md): the spec's names, their parameters, the ``fxc`` flags and
#: :func:`model_matrices` read this table. Adding a model is one entry here (docs: extending.md, "An agent model").
AGENT_MODELS: dict[str, AgentModel] = {
    "double_integrator": AgentModel(lambda _: _chain(2)),
    "single_integrator": AgentModel(lambda _: (np.zeros((1, 1)), np.ones((1, 1)))),
    "integrator_chain": AgentModel(
        lambda order: _chain(
            2 if order is None else validation.integer("order", order, CHAIN_ORDERS[0], CHAIN_ORDERS[-1])
        ),
        "order",
        int,
        "order of --agent-model integrator_chain (1-4, default 2)",
    ),
    "damped": AgentModel(
        _damped, "damping", float, f"drag c of --agent-model damped (1/s, default {DEFAULT_DAMPING:g})"
    ),
    "oscillator": AgentModel(
        _oscillator, "frequency", float, f"frequency of --agent-model oscillator (rad/s, default {DEFAULT_FREQUENCY:g})"
    ),
}
MODEL_NAMES = tuple(AGENT_MODELS)
#: The parameter each named model takes (a key of its spec beside ``"name"``); the others take none.
MODEL_PARAMETERS = {name: model.parameter for name, model in AGENT_MODELS.items() if model.parameter}
#: The previous release's flat arguments (deprecated), frozen: a newer model's parameter exists only in the spec.
FLAT_PARAMETERS = ("order", "damping", "frequency")


def model_matrices(name: Any, **parameters: Any) -> tuple[np.ndarray, np.ndarray]:
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
        parameters: the parameter of the model that has it (``order``, ``damping``, ``frequency``: a key of
            :data:`MODEL_PARAMETERS`' values); ``None`` for the default.

    Raises:
        ArgumentError naming ``agent_model`` (unknown name) or the parameter (out of range, or
        given to a model that has no such parameter).
    """
    name = validation.choice("agent_model", name, MODEL_NAMES)
    owners = {key: model for model, key in MODEL_PARAMETERS.items()}
    for parameter, value in parameters.items():
        if parameter not in owners:
            raise TypeError(f"model_matrices() got an unexpected keyword argument {parameter!r}")
        if value is not None and owners[parameter] != name:
            raise ArgumentError(
                f"{parameter}: only agent_model = {owners[parameter]!r} has a {parameter}, "
                f"got {parameter} = {value!r} with agent_model = {name!r}"
            )
    model = AGENT_MODELS[name]
    return model.matrices(parameters.get(model.parameter) if model.parameter else None)


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
