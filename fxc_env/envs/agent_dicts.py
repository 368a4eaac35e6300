"""The per-agent dicts of the PettingZoo API to and from the engine's arrays: observations, the action
dict, what the infos carry (metrics, draws, graph tensors) and the scale-free global state."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core import validation
from fxc_env.core.metrics import EpisodeMetrics
from fxc_env.core.validation import ArgumentError, ArgumentTypeError
from fxc_env.engine import ConsensusEngine, EpisodeDraw
from fxc_env.engine.graph_tensors import GRAPH_TENSOR_KEYS, edge_capacity, graph_tensors


def episode_metrics_rows(engine: ConsensusEngine) -> list[dict[str, float | int]]:
    """Each episode's metrics as a plain dict of numbers, ``(B,)`` dicts.

    The keys are the fields of :class:`fxc_env.core.metrics.EpisodeMetrics`. Unlike
    ``EpisodeMetrics.as_dict()`` (made for JSON), nothing is ``None``: a threshold never reached
    stays ``inf``, and a metric that is ``nan`` in :meth:`ConsensusEngine.batch_metrics` (it does
    not apply to the episode) is left out, so identically seeded runs give equal infos and replay
    buffers stay free of NaN. ``sampling_instants`` is an ``int``, every other value a ``float``.
    """
    columns = engine.batch_metrics()
    names = [field.name for field in dataclasses.fields(EpisodeMetrics)]
    rows = zip(*(columns[n].tolist() for n in names), strict=True)
    return [{n: v for n, v in zip(names, row, strict=True) if v == v} for row in rows]  # v != v only for NaN


def episode_draw_info(draw: EpisodeDraw) -> dict[str, Any]:
    """What a reset drew that every info of the episode carries (empty when nothing is drawn).

    ``u_max``: the input limit drawn from a set (a float, the same at reset and every step). The
    drawn graphs are no info (their length changes with the draw, and replay buffers need one
    shape per key): :meth:`ConsensusParallelEnv.episode_edges` gives them.
    """
    return {} if draw.u_max is None else {"u_max": float(draw.u_max)}


def normalized_state(engine: ConsensusEngine) -> np.ndarray:
    """The scale-free global state of every episode, ``(B, N * 2 dim + 3)``, in ``config.obs_dtype``.

    :meth:`fxc_env.engine.ConsensusEngine.normalized_state`: per agent the row
    ``[x_i - mean_j x_j, T_s (v_i - mean_j v_j)] / max(D, tiny)`` (agent major), then the clock
    ``t_k / T_s, T_{k+1} / T_s, k / K``, with ``D = e_x + T_s e_v`` the current disagreement
    (docs: environment.md, "The environment"); the rows lie in [-1, 1] by construction.
    """
    return np.asarray(engine.normalized_state(), dtype=engine.config.observation_dtype)


def initial_state_options(engine: ConsensusEngine, options: Any) -> tuple[Any, Any]:
    """``reset``'s options checked (:func:`~fxc_env.core.validation.reset_options`): ``(x0, v0)``, None where not given."""
    options = validation.reset_options("options", options)
    return tuple(engine.validate_state(f"options[{k!r}]", options[k]) if k in options else None for k in ("x0", "v0"))


def add_graph_info(infos: dict[str, dict[str, Any]], engine: ConsensusEngine, flat: np.ndarray) -> None:
    """The current graph's padded tensors of episode 0 in every info (docs: graph-tensors.md, "Graph tensors")."""
    tensors = graph_tensors(engine, flat[None], edge_capacity(engine.config))
    graph = {key: np.ascontiguousarray(value[0]) for key, value in zip(GRAPH_TENSOR_KEYS, tensors, strict=True)}
    graph["n_edges"] = int(tensors.n_edges[0])
    for info in infos.values():
        info.update(graph)


def observation_dicts(obs: np.ndarray, config: EnvConfig, agent_index: Mapping[str, int]) -> dict[str, Any]:
    """Flat observations ``(N, obs_size)`` as PettingZoo's dict over agents, in ``config.obs_format``."""
    if config.obs_format != "dict":
        return dict(zip(agent_index, obs, strict=True))
    layout = config.layout
    rows = obs[:, : layout.rows_end].reshape(len(obs), layout.slots, layout.row_size)
    parts = {"neighbours": rows, "mask": obs[:, layout.rows_end : layout.mask_end]}
    parts["clock"] = obs[:, layout.mask_end : layout.clock_end]
    if layout.limit_feature:
        parts["input_limit"] = obs[:, layout.clock_end :]
    return {agent: {key: part[i] for key, part in parts.items()} for agent, i in agent_index.items()}


def action_array(
    actions: Any, agents: list[str], agent_set: set[str], size: int, check: Callable[[str, Any], np.ndarray]
) -> np.ndarray:
    """A dict over every agent of ``(2 dim,)`` actions as one float64 ``(1, N, 2 dim)`` array.

    ``check(agent, action)`` names a bad one (its shape, type or entries); a missing or
    unknown agent is named here.
    """
    if type(actions) is not dict and not isinstance(actions, Mapping):
        raise ArgumentTypeError(f"actions: expected a dict from agent name to action, got {type(actions).__name__}")
    if actions.keys() != agent_set:  # every agent is live while the episode runs
        unknown = sorted(set(actions) - agent_set, key=str)
        if unknown:
            raise ArgumentError(
                f"actions: unknown agent(s) {unknown}; expected keys agent_0 .. agent_{len(agents) - 1}"
            )
        missing = [agent for agent in agents if agent not in actions]
        raise ArgumentError(f"actions: missing an action for agent(s) {missing}")
    try:
        stacked = np.array([actions[agent] for agent in agents])
    except (TypeError, ValueError):
        stacked = None  # ragged: the loop below names the agent
    array = stacked.astype(np.float64) if stacked is not None and stacked.dtype.kind in "iuf" else None
    if array is None or array.shape != (len(agents), size) or not np.isfinite(array).all():
        for agent in agents:
            check(agent, actions[agent])
    return array[None]
