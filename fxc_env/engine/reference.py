"""The paper's plan (eq. 11) from the neighbour sums alone, where the agents observe exactly.

The reference controller plans ``a_x = (sum_j (x_j - x_i) + T sum_j (v_j - v_i)) / (d_i + 1)`` and
``a_v = sum_j (v_j - v_i) / (d_i + 1)`` over the in-neighbours j of the coming interval's graph
(:class:`~fxc_env.policies.reference.ReferencePolicy` reads these sums off the observation). When the
observation holds the true relative states (:func:`exact_observations`), :class:`NeighbourPlans`
forms the sums straight from the state with the observation's own differences ``z_j - z_i``, and
:meth:`ConsensusEngine.step_reference <fxc_env.engine.ConsensusEngine.step_reference>` plays the
plans with the minimum-energy input and the exact step: the observation path's interval, bit for
bit with raw observations (to rounding with normalized ones), without its ``(B, N, obs_size)``
observations (docs: performance.md, "The reference fast path").

The work is done by a compiled kernel, :data:`KERNEL` (``fxc_env/engine/_reference_kernel.c``,
built by ``pip install`` from pyproject.toml's ext-modules): per agent, in one pass, the gather of
the in-neighbours' ``[x_j, v_j]``, the sums slot by slot, the plan, and for unlimited double
integrators the whole interval (the input's ends, the exact step, energy, peak and the
disagreement's ranges) while the gathered rows are in the cache: numpy's operations in numpy's
order, so the same values, where numpy needs some twenty passes over the agents and a gather
that alone costs about two thirds of a sparse product. An install without a C compiler has no kernel: then
``ReferencePolicy.step`` builds the observations and ``step_reference`` refuses, saying why.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.validation import ArgumentError

from .agents import Interval
from .observations import noise_free

try:
    #: The compiled kernel of the reference interval; None where the install had no C compiler.
    import fxc_env.engine._reference_kernel as KERNEL
except ImportError:  # the observation path serves
    KERNEL = None


def exact_observations(config: EnvConfig, backend: Any) -> bool:
    """Whether the agents' observations are the true relative states (numpy engine, double integrators).

    Not so with measurement noise (``obs_noise``), rows rounded to a quantum (``obs_resolution``),
    lost links (``link_dropout``), float32 observations (rounded rows), general linear agents
    (``agent_model``: their plan is another map) or no in-neighbour slots; nor on torch or a
    float32 engine (the kernel reads numpy's float64 memory).
    """
    return noise_free(config, backend) and config.obs_dtype == "float64" and backend.dtype == np.float64


class NeighbourPlans:
    """The reference's plans ``[a_x, a_v]`` ``(B, N, 2 dim)`` in metres and m/s, from the neighbour sums alone.

    Args:
        config: the environment's settings (:func:`exact_observations` decides whether this applies).
        backend: the engine's array backend.
    """

    def __init__(self, config: EnvConfig, backend: Any) -> None:
        observe_exactly = exact_observations(config, backend)
        #: :meth:`plans` applies: the agents observe exactly and the install built :data:`KERNEL`.
        self.exact = observe_exactly and KERNEL is not None
        #: :meth:`interval` applies too: unlimited double integrators.
        self.fusable = self.exact and config.u_max_choices is None
        self._refusal = None if self.exact else _refusal(observe_exactly)
        self.config = config
        self.n_episodes = backend.n_episodes
        self._plans: np.ndarray | None = None
        #: ``1 / (d_i + 1)`` ``(N,)`` by row of the graph table whose rows they are (made at first use).
        self._weights: tuple[Any, dict[int, np.ndarray]] = (None, {})

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_plans": None, "_weights": (None, {})}  # scratch space, made again on first use

    def _weight(self, graphs: Any, graph: int) -> np.ndarray:
        """``1 / (d_i + 1)`` ``(N,)`` of row ``graph`` of ``graphs`` (the table's own degrees, cached)."""
        if self._weights[0] is not graphs:
            self._weights = (graphs, {})
        cached = self._weights[1]
        if graph not in cached:
            cached[graph] = 1.0 / (graphs.mask_features[graph].sum(axis=1) + 1.0)
        return cached[graph]

    def _episodes(self, graphs: Any, clock: Any) -> list[tuple[int, np.ndarray, np.ndarray, float]]:
        """Per episode: its index, its coming graph's in-neighbour slots ``(N, slots)``, ``1 / (d_i + 1)`` and ``T``."""
        if self._refusal is not None:
            raise ArgumentError(self._refusal)
        clock.check_can_step()
        intervals = np.broadcast_to(np.ravel(clock.interval(1)), (self.n_episodes,))
        rows = (int(graph) for graph in graphs.graph_ids)
        return [(b, graphs.neighbour_index[g], self._weight(graphs, g), intervals[b]) for b, g in enumerate(rows)]

    def plans(self, state: np.ndarray, clock: Any, graphs: Any) -> np.ndarray:
        """Every agent's plan at ``t_k`` for the state ``(B, N, 2, dim)`` and each episode's coming graph.

        Per agent, in :data:`KERNEL`: gather ``[x_j, v_j]`` of every slot, subtract the agent's own
        (padded slots give exact zeros), add the slots up, then ``a_v = S_v / (d_i + 1)`` and
        ``a_x = (S_x + T S_v) / (d_i + 1)``, the policy's arithmetic. A reused buffer: consume it
        before the next call. Refused (:class:`ArgumentError` naming ``step_reference``) unless
        :attr:`exact`.
        """
        b, n, dim = self.n_episodes, self.config.n_agents, self.config.dim
        if self._plans is None:
            self._plans = np.empty((b, n, 2 * dim))
        for episode, index, weight, T in self._episodes(graphs, clock):
            KERNEL.plans(state[episode], index, weight, n, dim, T, self._plans[episode])
        return self._plans

    def interval(
        self, state: np.ndarray, clock: Any, graphs: Any, agents: Any, local_scale: Any, out: np.ndarray
    ) -> Interval:
        """The coming interval under :meth:`plans`' plans, its new state in ``out`` (numpy's spare buffer).

        Where :attr:`fusable` holds, :data:`KERNEL` makes it in one pass per episode: the state at
        ``t_{k+1}`` ``(B, N, 2, dim)``, the input's ends ``(B, N, dim)``, its energy and peak
        ``(B, N)`` and (``dim = 1``) the ranges of x and v, the very values of
        ``agents.advance(state, plans(...))`` (:class:`~fxc_env.engine.agents.Interval`). Else
        ``agents`` play the plans (with ``local_scale``, as :meth:`ConsensusEngine.step
        <fxc_env.engine.ConsensusEngine.step>` does). Refused, like :meth:`plans`, unless :attr:`exact`.
        """
        if not self.fusable:
            return agents.advance(state, self.plans(state, clock, graphs), clock, local_scale, out, raw_plans=True)
        b, n, dim = self.n_episodes, self.config.n_agents, self.config.dim
        u0, u1, energy, peak, ranges = (np.empty(shape) for shape in ((b, n, dim),) * 2 + ((b, n),) * 2 + ((b, 2),))
        for episode, index, weight, T in self._episodes(graphs, clock):
            outputs = (out[episode], u0[episode], u1[episode], energy[episode], peak[episode], ranges[episode])
            KERNEL.interval(state[episode], index, weight, n, dim, T, *outputs)
        disagreement = ranges @ agents.range_weights if dim == 1 else agents.disagreement(out)
        return Interval(out, energy, peak, u0, u1, agents.no_saturation, disagreement=disagreement)


def _refusal(observe_exactly: bool) -> str:
    """Why ``step_reference`` does not apply: the observations are not exact, or the kernel was not built."""
    if observe_exactly:
        return (
            "step_reference: the paper's plan from exact neighbour sums needs the compiled kernel "
            "fxc_env.engine._reference_kernel, which this install did not build (no C compiler at pip install); "
            "ReferencePolicy(config).step(engine) plays the same interval from the observations"
        )
    return (
        "step_reference: the paper's plan from exact neighbour sums needs exact observations on numpy "
        "(no obs_noise, obs_resolution, link_dropout, float32 obs_dtype or float32 engine; double-integrator agents); "
        "step with ReferencePolicy(config)(observations()) instead"
    )
