"""The Gymnasium spaces of one agent and of the global state, built from an :class:`EnvConfig`.

Shared by the PettingZoo environment and the SB3 VecEnv so both expose the same spaces.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from fxc_env.config import EnvConfig
from fxc_env.layout import CLOCK_SIZE


def observation_space(config: EnvConfig) -> spaces.Space:
    """One agent's observation: a flat ``Box`` (rows, mask, clock) or the ``Dict`` form.

    Rows lie in [-1, 1] in ``normalized`` mode and are unbounded in ``raw`` mode; the mask
    and the clock lie in [0, 1]. All float64.
    """
    layout = config.layout
    row_bound = 1.0 if config.obs_mode == "normalized" else np.inf
    rows = spaces.Box(-row_bound, row_bound, shape=(layout.slots, layout.row_size), dtype=np.float64)
    mask = spaces.Box(0.0, 1.0, shape=(layout.slots,), dtype=np.float64)
    clock = spaces.Box(0.0, 1.0, shape=(CLOCK_SIZE,), dtype=np.float64)
    if config.obs_format == "dict":
        return spaces.Dict({"neighbours": rows, "mask": mask, "clock": clock})
    low = np.concatenate([rows.low.ravel(), mask.low, clock.low])
    high = np.concatenate([rows.high.ravel(), mask.high, clock.high])
    return spaces.Box(low, high, dtype=np.float64)


def action_space(config: EnvConfig) -> spaces.Box:
    """One agent's action ``Box(-b, b, (2 dim,), float64)`` with ``b = config.action_bound``."""
    bound = config.action_bound
    return spaces.Box(-bound, bound, shape=(config.action_size,), dtype=np.float64)


def state_space(config: EnvConfig) -> spaces.Box:
    """The global state ``(N, 2 dim)``: rows ``[x_i, v_i]``, unbounded, float64."""
    return spaces.Box(-np.inf, np.inf, shape=(config.n_agents, 2 * config.dim), dtype=np.float64)
