"""The paper's plan (eq. 11) from the neighbour sums alone, where the agents observe exactly.

The reference controller plans ``a_x = (sum_j (x_j - x_i) + T sum_j (v_j - v_i)) / (d_i + 1)`` and
``a_v = sum_j (v_j - v_i) / (d_i + 1)`` over the in-neighbours j of the coming interval's graph
(:class:`~fxc_env.policies.reference.ReferencePolicy` reads these sums off the observation). When the
observation holds the true relative states (:func:`exact_observations`), :class:`NeighbourPlans`
forms the sums straight from the state, block by block of agents in the cache, with the
observation's own differences ``z_j - z_i`` (so they round alike: bit for bit with raw
observations), and :meth:`ConsensusEngine.step_reference <fxc_env.engine.ConsensusEngine.step_reference>`
plays the plans with the minimum-energy input and the exact step: the observation path's interval
to rounding, without its ``(B, N, obs_size)`` observations (docs: performance.md, "The reference
fast path").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.validation import ArgumentError

from .observations import noise_free

#: Agents per block of :meth:`NeighbourPlans.plans` (the gathered rows, 1 MiB at 4 slots and dim = 1, stay in the cache).
BLOCK_AGENTS = 16384


def exact_observations(config: EnvConfig, backend: Any) -> bool:
    """Whether the agents' observations are the true relative states (numpy engine, double integrators).

    Not so with measurement noise (``obs_noise``), rows rounded to a quantum (``obs_resolution``),
    lost links (``link_dropout``), float32 observations (rounded rows), general linear agents
    (``agent_model``: their plan is another map) or no in-neighbour slots; nor on torch (the
    gather is numpy's ``take``).
    """
    return noise_free(config, backend) and config.obs_dtype == "float64"


class NeighbourPlans:
    """The reference's plans ``[a_x, a_v]`` ``(B, N, 2 dim)`` in metres and m/s, from the neighbour sums alone.

    Args:
        config: the environment's settings (:func:`exact_observations` decides whether this applies).
        backend: the engine's array backend.
    """

    def __init__(self, config: EnvConfig, backend: Any) -> None:
        #: The agents observe exactly: :meth:`plans` applies.
        self.exact = exact_observations(config, backend)
        self.config = config
        self.n_episodes = backend.n_episodes
        self._plans: np.ndarray | None = None
        #: ``1 / (d_i + 1)`` ``(N, 2 dim)`` by row of the graph table whose rows they are (made at first use).
        self._weights: tuple[Any, dict[int, np.ndarray]] = (None, {})

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_plans": None, "_weights": (None, {})}  # scratch space, made again on first use

    def _weight(self, graphs: Any, graph: int) -> np.ndarray:
        """``1 / (d_i + 1)`` of row ``graph`` of ``graphs`` (the table's own degrees, cached), once per plan entry ``(N, 2 dim)``.

        Repeated along the row so that multiplying the plans by it is one contiguous run (a
        ``(N, 1)`` column broadcast over ``2 dim`` entries makes numpy loop per agent).
        """
        if self._weights[0] is not graphs:
            self._weights = (graphs, {})
        cached = self._weights[1]
        if graph not in cached:
            weight = 1.0 / (graphs.mask_features[graph].sum(axis=1, keepdims=True) + 1.0)
            cached[graph] = np.repeat(weight, 2 * self.config.dim, axis=1)
        return cached[graph]

    def plans(self, state: np.ndarray, clock: Any, graphs: Any) -> np.ndarray:
        """Every agent's plan at ``t_k`` for the state ``(B, N, 2, dim)`` and each episode's coming graph.

        Per block of agents (:meth:`GraphTable.blocks <fxc_env.engine.graph_table.GraphTable.blocks>`),
        in the cache: gather ``[x_j, v_j]`` of every slot, subtract the agent's own (padded slots
        give exact zeros), add the slots up, then ``a_v = S_v / (d_i + 1)`` and
        ``a_x = (S_x + T S_v) / (d_i + 1)``, the policy's arithmetic. A reused buffer: consume it
        before the next call. Refused (:class:`ArgumentError` naming ``step_reference``) unless
        the observations are exact.
        """
        if not self.exact:
            raise ArgumentError(
                "step_reference: the paper's plan from exact neighbour sums needs exact observations on numpy "
                "(no obs_noise, obs_resolution, link_dropout or float32 obs_dtype; double-integrator agents); "
                "step with ReferencePolicy(config)(observations()) instead"
            )
        clock.check_can_step()
        b, n, dim, slots = self.n_episodes, self.config.n_agents, self.config.dim, self.config.layout.slots
        if self._plans is None:
            self._plans = np.empty((b, n, 2 * dim))
        intervals = np.broadcast_to(np.ravel(clock.interval(1)), (b,))
        block = min(BLOCK_AGENTS, n)
        gathered, moved = np.empty((slots, block, 2 * dim)), np.empty((block, dim))
        for episode in range(b):
            flat = state[episode].reshape(n, 2 * dim)  # [x | v] per agent
            graph = int(graphs.graph_ids[episode])
            weight = self._weight(graphs, graph)
            for start, index, _ in graphs.blocks(graph, block):
                stop = start + index.shape[1]
                rows, sums = gathered[:, : stop - start], self._plans[episode, start:stop]
                np.take(flat, index, axis=0, out=rows, mode="clip")
                np.subtract(rows, flat[start:stop], out=rows)  # z_j - z_i
                np.add.reduce(rows, axis=0, out=sums)  # [S_x | S_v]
                np.multiply(sums[:, dim:], intervals[episode], out=moved[: stop - start])
                sums[:, :dim] += moved[: stop - start]
                np.multiply(sums, weight[start:stop], out=sums)  # over d_i + 1
        return self._plans
