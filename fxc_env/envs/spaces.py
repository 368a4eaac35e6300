"""The Gymnasium spaces of one agent and of the global state, built from an :class:`EnvConfig`.

Shared by the PettingZoo environments and the SB3 VecEnv so all expose the same spaces.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from fxc_env.config import EnvConfig
from fxc_env.config.layout import CLOCK_SIZE


def observation_space(config: EnvConfig) -> spaces.Space:
    """One agent's observation: a flat ``Box`` (rows, mask, clock) or the ``Dict`` form.

    Rows lie in [-1, 1] in ``normalized`` mode and are unbounded in ``raw`` mode; the mask
    and the clock lie in [0, 1]; with an input limit ``u_max`` a last entry (``"input_limit"``
    in the dict form, :func:`fxc_env.engine.limit_feature`) lies in [-1, 1]. The dtype is
    ``config.obs_dtype`` (float64 by default).
    """
    layout = config.layout
    dtype = config.observation_dtype
    if config.obs_format != "dict":
        low, high = observation_bounds(config)
        return spaces.Box(low.astype(dtype), high.astype(dtype), dtype=dtype)
    row_bound = 1.0 if config.obs_mode == "normalized" else np.inf
    rows = spaces.Box(-row_bound, row_bound, shape=(layout.slots, layout.row_size), dtype=dtype)
    parts = {"neighbours": rows, "mask": spaces.Box(0.0, 1.0, shape=(layout.slots,), dtype=dtype)}
    parts["clock"] = spaces.Box(0.0, 1.0, shape=(CLOCK_SIZE,), dtype=dtype)
    if layout.limit_feature:
        parts["input_limit"] = spaces.Box(-1.0, 1.0, shape=(1,), dtype=dtype)
    return spaces.Dict(parts)


def observation_bounds(config: EnvConfig) -> tuple[np.ndarray, np.ndarray]:
    """The flat observation's bounds (rows, mask, clock, limit entry), float64 ``(obs_size,)`` each."""
    layout = config.layout
    row = 1.0 if config.obs_mode == "normalized" else np.inf
    low = [np.full(layout.rows_end, -row), np.zeros(layout.slots + CLOCK_SIZE), [-1.0] * layout.limit_feature]
    high = [np.full(layout.rows_end, row), np.ones(layout.slots + CLOCK_SIZE), [1.0] * layout.limit_feature]
    return np.concatenate(low), np.concatenate(high)


def action_space(config: EnvConfig) -> spaces.Box:
    """One agent's action ``Box(-b, b, (2 dim,), float64)`` with ``b = config.action_bound``."""
    bound = config.action_bound
    return spaces.Box(-bound, bound, shape=(config.action_size,), dtype=np.float64)


def state_size(config: EnvConfig) -> int:
    """Length of the ``global_state="normalized"`` vector: ``N * 2 dim`` rows and the 3 clock features."""
    return config.n_agents * config.n_states * config.dim + CLOCK_SIZE


def state_space(config: EnvConfig) -> spaces.Box:
    """The global state of one episode.

    ``global_state="raw"`` (default): ``(N, 2 dim)`` rows ``[x_i, v_i]``, unbounded, float64.
    ``global_state="normalized"``: the flat ``(N * 2 dim + 3,)`` vector of
    :func:`fxc_env.envs.agent_dicts.normalized_state`, rows in [-1, 1] and the clock in [0, 1],
    in ``config.obs_dtype``.
    """
    if config.global_state == "normalized":
        rows = config.n_agents * config.n_states * config.dim
        dtype = config.observation_dtype
        low = np.concatenate([np.full(rows, -1.0, dtype=dtype), np.zeros(CLOCK_SIZE, dtype=dtype)])
        return spaces.Box(low, np.ones(state_size(config), dtype=dtype), dtype=dtype)
    return spaces.Box(-np.inf, np.inf, shape=(config.n_agents, config.n_states * config.dim), dtype=np.float64)
