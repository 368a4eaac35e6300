"""Where things sit in one agent's flat observation vector (docs: environment.md, "Observation").

The environment writes observations in this layout and every policy reads them through it,
so both agree by construction.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

#: Clock features at the end of every observation: ``t_k / T_s``, ``T_{k+1} / T_s``, ``k / K``.
CLOCK_SIZE = 3


@dataclass(frozen=True, eq=False)
class ObservationLayout:
    """Where things sit in one agent's flat observation vector.

    ``[rows (slots * n * dim) | mask (slots) | clock (3) | input limit (0 or 1)]``; row r
    is ``[x_j - x_i (dim), v_j - v_i (dim)]`` for the r-th in-neighbour j (ascending), zero
    padded (``n = 2``; a general linear agent's row holds its n state components, each ``dim``
    numbers). ``slots`` is the largest in-degree over the topology set (``d_max``), or more
    when ``obs_slots`` asks for room (a policy then fits several topologies). In
    ``normalized`` mode rows are ``(x_j - x_i) / s_i`` and ``T (v_j - v_i) / s_i``. With an
    input limit ``u_max`` the last entry tells how far it binds on the coming interval
    (:func:`fxc_env.engine.limit_feature`).
    """

    slots: int
    dim: int
    limit_feature: bool = False
    #: State components per axis (2 for the double integrator: position and velocity).
    n_states: int = 2

    @cached_property
    def row_size(self) -> int:
        return self.n_states * self.dim

    @cached_property
    def rows_end(self) -> int:
        return self.slots * self.row_size

    @cached_property
    def mask_end(self) -> int:
        return self.rows_end + self.slots

    @cached_property
    def clock_end(self) -> int:
        return self.mask_end + CLOCK_SIZE

    @cached_property
    def size(self) -> int:
        """Length of the flat observation."""
        return self.clock_end + int(self.limit_feature)

    def flat(self, observation: np.ndarray | Mapping[str, Any]) -> np.ndarray:
        """A flat float64 ``(..., size)`` observation from a flat or a dict observation."""
        if isinstance(observation, Mapping):
            neighbours = np.asarray(observation["neighbours"], dtype=np.float64)
            parts = (neighbours.reshape((*neighbours.shape[:-2], -1)), observation["mask"], observation["clock"])
            if self.limit_feature:
                parts = (*parts, observation["input_limit"])
            return np.concatenate([np.asarray(part, dtype=np.float64) for part in parts], axis=-1)
        return np.asarray(observation, dtype=np.float64)

    def split(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(..., size)`` -> rows ``(..., slots, n, dim)``, mask ``(..., slots)``, clock ``(..., 3)``."""
        lead = obs.shape[:-1]
        rows = obs[..., : self.rows_end].reshape((*lead, self.slots, self.n_states, self.dim))
        return rows, obs[..., self.rows_end : self.mask_end], obs[..., self.mask_end : self.clock_end]
