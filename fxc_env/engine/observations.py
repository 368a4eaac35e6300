"""What the agents measure at ``t_k`` and the observations built from it (the card's Observation Space).

Agent i receives from every in-neighbour j of the coming interval's graph the relative state
``[x_j - x_i, v_j - v_i]`` (paper Section 2), with measurement noise and link dropout where
the config asks; its local scale is ``s_i = max(|x_j - x_i|, T |v_j - v_i|)`` over the rows
(``T_s`` in place of ``T`` with ``action_mode="plan_balanced"``: :attr:`EnvConfig.velocity_weight`; the environment
card's Observation Space). A flat observation is the rows (divided by ``s_i`` in normalized
mode, velocities times ``T``, or ``T_s``), the slot mask, the clock and, with an input limit, the limit
feature (:func:`limit_feature`). Each instant's measurements are drawn once and cached
until the engine moves (:meth:`Observer.invalidate`).

**numpy fast path.** Without noise or dropout, on one shared graph in lock step, the flat
observation is built agent block by agent block (:data:`BLOCK_AGENTS`), with the same
element-wise operations in the same order, so the values are identical (docs: performance.md,
"The observation fast path").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core import slots, validation
from fxc_env.core.arrays import namespace
from fxc_env.core.validation import ArgumentError

from .backend import TINY

#: Agents per episode from which the numpy fast path pays (it loops over episodes, then blocks).
BLOCKED_FROM = 2048
#: Agents per block of the numpy fast path (a block's buffers, about 5 MiB at 4 slots, stay in the L3 cache).
BLOCK_AGENTS = 16384


def limit_feature(u_max: Any, interval: Any, scale: Any) -> Any:
    """How far the input limit binds on the coming interval, scale-free, in ``[-1, 1]``.

    ``rho = u_max T^2 / s_i`` compares the limit with the input a plan at agent i's scale
    needs: the paper's controller starts an interval at about ``6 e / T^2`` (eq. 11), at
    most ``10 s_i / T^2``, so ``rho`` below about 10 means the limit cuts the planned
    input and ``rho >> 10`` that it is out of reach. The feature is ``l / (1 + |l|)`` with
    ``l = log10(rho)``: decades spread evenly (0 at ``rho = 1``, ±0.5 one decade either
    side, ±0.75 three), bounded without a hard clip; ``s_i = 0`` (nothing to correct) gives
    1. Scaling the state and ``u_max`` by the same factor leaves it unchanged. Shape of
    ``scale``, e.g. ``(B, N)``; numpy arrays or torch tensors.
    """
    xp = namespace(scale)
    with np.errstate(divide="ignore", invalid="ignore"):
        # s = 0 takes its log of 1 (and the feature 1): no infinity on the autograd path, whose
        # gradient (0 times infinity) would be NaN.
        seen = scale > 0
        decades = xp.log10(u_max * interval * interval) - xp.log10(xp.where(seen, scale, xp.ones_like(scale)))
        usable = seen & xp.isfinite(decades)
        return xp.where(usable, decades / (1.0 + xp.abs(decades)), xp.ones_like(decades))


def _over_scale(rows: Any, scale: Any, backend: Any) -> Any:
    """``rows / max(s, tiny)`` ``(B, N, F)`` for scales ``(B, N)``, with the rows of ``s = 0`` (all 0) divided by 1.

    The same values (``s = 0`` only when every row is 0), but an agent that sees no
    disagreement is not divided by ``tiny``: its rows' gradient would be ~1e308 times the
    state's and, cancelling in the state's gradient, leave nothing else of it.
    """
    xp = backend.xp
    floored = xp.where(scale > 0, xp.maximum(scale, backend.full((), backend.tiny)), xp.ones_like(scale))
    return rows / floored[..., None]


def _subtract(rows: Any, own: Any) -> Any:
    """``rows - own``: in place into the gathered numpy rows, a new tensor on torch."""
    if isinstance(rows, np.ndarray):
        rows -= own
        return rows
    return rows - own


def noise_free(config: EnvConfig, backend: Any) -> bool:
    """Whether the observations are the sampled relative states as they are, up to their dtype: on numpy, of
    double integrators (``agent_model``: none), with no measurement noise (``obs_noise``), no quantum
    (``obs_resolution``), no lost links (``link_dropout``), and some in-neighbour slots."""
    return bool(
        backend.is_numpy
        and config.model is None
        and config.obs_noise == 0
        and config.obs_resolution == 0
        and config.link_dropout == 0
        and config.layout.slots
    )


class Observer:
    """The engine's measurements and observations (cached per instant).

    Args:
        config: the environment's settings (modes, noise, dropout, layout).
        backend: the engine's array backend (with raw float32 observations, told the largest
            row a step may leave: :meth:`~fxc_env.engine.backend.NumpyBackend.limit_rows`).
        tables: the engine's per-instant tables (:class:`~fxc_env.engine.clock.InstantTables`).
    """

    def __init__(self, config: EnvConfig, backend: Any, tables: Any) -> None:
        if (config.obs_dtype, config.obs_mode) == ("float32", "raw"):
            # A raw row is a difference of two states: one beyond float32's range would observe as inf,
            # so the backend refuses (numpy) or flags (torch) a step after which one is.
            backend.limit_rows(
                validation.float32_row_limit(config.obs_noise) - config.obs_resolution,
                [config.settling_time**level for level in range(config.n_states)],
            )
        self.config = config
        self.layout = config.layout
        self.backend = backend
        self.tables = tables
        self.normalized = bool(config.obs_mode == "normalized" and self.layout.slots)
        #: The numpy fast path applies (:func:`noise_free`, episodes of at least :data:`BLOCKED_FROM` agents).
        self.blocked = noise_free(config, backend) and config.n_agents >= BLOCKED_FROM
        #: What the local scale weighs velocities by: ``T_s`` (``plan_balanced``), else None (``T_{k+1}``).
        self.velocity_weight = config.velocity_weight
        self._measured: tuple | None = None
        self._scale: Any = None
        self._buffers: tuple | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_buffers"] = None  # scratch space, made again on first use
        return state

    def invalidate(self) -> None:
        """The state or the instant changed: measurements are drawn anew on next use."""
        self._measured = None
        self._scale = None

    def detach(self) -> None:
        """torch: the cached measurements with no autograd history (the same draws: noise is not drawn again)."""
        if self._measured is not None:
            self._measured = tuple(part.detach() if hasattr(part, "detach") else part for part in self._measured)
            self._scale = self._measured[2]
        elif self._scale is not None:
            self._scale = self._scale.detach()

    def measure(self, state: Any, clock: Any, graphs: Any, uniform: Callable, normal: Callable) -> tuple[Any, Any, Any]:
        """Rows ``(B, N, slots, n, dim)``, mask ``(B, N, slots)`` or ``(N, slots)``, local scale ``(B, N)``.

        Rows are ``[z_j - z_i]`` per in-neighbour slot (padded slots point at i itself and
        hold exact zeros), with noise (``normal``) and dropout (``uniform``), rounded to
        ``obs_resolution``; the mask is 1 for a row received; the scale is in metres.
        """
        if self._measured is not None:
            return self._measured
        c, xp, backend = self.config, self.backend.xp, self.backend
        # Gather [x_j, v_j] together (one random access per edge).
        rows, mask = graphs.gather(state)
        # numpy writes into the gathered rows; torch makes new tensors (no in-place write on the autograd path).
        rows = _subtract(rows, state[:, :, None])
        if c.link_dropout > 0:
            mask = mask * xp.astype(uniform((backend.n_episodes, *mask.shape[-2:])) >= c.link_dropout, backend.dtype)
            rows = rows * mask[..., None, None]
        if c.obs_noise > 0:
            rows = rows + (c.obs_noise * mask[..., None, None]) * normal(tuple(rows.shape))
        if c.obs_resolution > 0:  # rounded to the quantum (half to even: |row| <= q / 2 reads 0)
            rows = c.obs_resolution * xp.round(rows / c.obs_resolution)
        if c.model is not None:
            # General agents: the largest |z_j - z_i| per component in position units (row_scales).
            largest = (
                xp.max(xp.abs(rows), axis=(-3, -1))
                if self.layout.slots
                else backend.zeros((*rows.shape[:-3], c.n_states))
            )
            scale = xp.max(largest * clock.per_instant(self.tables.row_scales), axis=-1)
        else:
            if backend.is_numpy:  # numpy fast path: a loop over the few slot columns (3x, see core.slots)
                largest = slots.max_abs_rows(rows)
            elif self.layout.slots:
                largest = xp.max(xp.abs(rows), axis=(-3, -1))
            else:
                largest = backend.zeros((*rows.shape[:-3], 2))
            weight = clock.interval(1) if self.velocity_weight is None else self.velocity_weight
            scale = xp.maximum(largest[..., 0], weight * largest[..., 1])
        self._measured = (rows, mask, scale)
        self._scale = scale
        return self._measured

    def local_scale(self, state: Any, clock: Any, graphs: Any, uniform: Callable, normal: Callable) -> Any:
        """Each agent's local scale ``s_i`` at ``t_k`` (metres), ``(B, N)``; 0 if it sees no disagreement."""
        return self._scale if self._scale is not None else self.measure(state, clock, graphs, uniform, normal)[2]

    def reference_plan(self, state: Any, clock: Any, graphs: Any, uniform: Callable, normal: Callable) -> Any:
        """The paper's plan (eq. 11) at ``t_k`` in the action's units, ``(B, N, 2 dim)`` (double integrator).

        ``a_x = (sum_j (x_j - x_i) + T sum_j (v_j - v_i)) / (d_i + 1)``, ``a_v = sum_j (v_j - v_i) / (d_i + 1)``
        over the rows received (noise and dropout included, as the observation has them);
        normalized: ``(a_x / s_i, T a_v / s_i)``, what :class:`~fxc_env.policies.reference.ReferencePolicy`
        reads off the observation. ``action_mode="residual"`` adds it to the action.
        """
        xp, T = self.backend.xp, clock.interval(2)
        rows, mask, scale = self.measure(state, clock, graphs, uniform, normal)
        sums = xp.sum(rows, axis=2)  # (B, N, 2, dim); padded and dropped rows are 0
        sum_x, sum_v = sums[..., 0, :], sums[..., 1, :]
        weight = 1.0 / (xp.sum(mask, axis=-1) + 1.0)[..., None]  # 1 / (d_i + 1), (B or 1, N, 1)
        if self.normalized:
            plan = xp.concat([sum_x + T * sum_v, T * sum_v], axis=-1)
            return _over_scale(weight * plan, scale, self.backend)
        return xp.concat([weight * (sum_x + T * sum_v), weight * sum_v], axis=-1)

    def plans(self, actions: Any, state: Any, clock: Any, graphs: Any, uniform: Callable, normal: Callable) -> Any:
        """``actions`` ``(B, N, 2 dim)`` as the agents take them: with ``action_mode="residual"`` plus :meth:`reference_plan`.

        Normalized residuals correct velocities in units of ``s / T_s`` (``a_v`` changes by
        ``s alpha_v / T_s``, not the plan's ``s alpha_v / T``), so one ``alpha_v`` moves the
        disagreement about as much on every interval of the schedule as one ``alpha_x``
        (the card's Action Space). Raw residuals are added as given; other modes return ``actions``.
        """
        if self.config.action_mode != "residual":
            return actions
        if self.config.obs_mode == "normalized":
            actions = actions * clock.per_instant(self.tables.residual_factors)
        return actions + self.reference_plan(state, clock, graphs, uniform, normal)

    def observe(
        self, state: Any, clock: Any, graphs: Any, u_max: Any, uniform: Callable, normal: Callable, out: Any = None
    ) -> Any:
        """Every agent's flat observation ``(B, N, obs_size)`` at ``t_k``; ``out`` (numpy) is filled if given.

        ``out`` other than a float64 numpy array ``(B, N, obs_size)`` raises :class:`ArgumentError` naming it.

        In normalized mode the rows are divided by the local scale; division (not
        multiplication by ``1/s``) keeps every entry within [-1, 1].
        """
        layout, xp, backend = self.layout, self.backend.xp, self.backend
        b, n = backend.n_episodes, self.config.n_agents
        if out is not None and (
            not isinstance(out, np.ndarray) or out.dtype != np.float64 or out.shape != (b, n, layout.size)
        ):
            raise ArgumentError(f"out: expected a float64 numpy array of shape {(b, n, layout.size)}, got {out!r:.60}")
        if self.blocked and graphs.same_graph and self._measured is None:
            obs = np.empty((b, n, layout.size)) if out is None else out
            self._scale = self._observe_blocked(obs, state, clock, graphs)
            if layout.limit_feature:
                obs[..., layout.clock_end] = limit_feature(u_max[:, None], clock.interval(), self._scale)
            return obs
        raw, mask, scale = self.measure(state, clock, graphs, uniform, normal)
        if backend.is_numpy and not clock.per_episode:
            obs = np.empty((b, n, layout.size)) if out is None else out
            if self.normalized:
                # numpy fast path: whole rows at once into the output, x parts times 1 and v parts
                # times T, then over s (numpy's inner loops over an agent's whole row: 3x at dim = 2).
                np.multiply(
                    raw.reshape(b, n, -1), clock.per_instant(self.tables.row_factors), out=obs[..., : layout.rows_end]
                )
                obs[..., : layout.rows_end] /= np.maximum(scale, TINY)[:, :, None]
            else:
                obs[..., : layout.rows_end] = raw.reshape(b, n, -1)
            obs[..., layout.rows_end : layout.mask_end] = mask
            obs[..., layout.mask_end : layout.clock_end] = clock.per_instant(self.tables.features)
            if layout.limit_feature:
                obs[..., layout.clock_end] = limit_feature(u_max[:, None], clock.interval(), scale)
            return obs
        rows = xp.reshape(raw, (b, n, -1))
        if self.normalized:
            rows = _over_scale(rows * clock.per_instant(self.tables.row_factors), scale, backend)
        zeros = backend.zeros((b, n, 1))
        parts = [rows, mask + zeros, clock.per_instant(self.tables.features) + zeros]
        if layout.limit_feature:
            parts.append(limit_feature(u_max[:, None], clock.interval(1), scale)[..., None])
        return xp.concat(parts, axis=-1)

    def _observe_blocked(self, obs: np.ndarray, state: np.ndarray, clock: Any, graphs: Any) -> np.ndarray:
        """numpy fast path of :meth:`observe`: observations built block by block; returns the scale ``(B, N)``.

        Per block of agents (:class:`_Block`): gather ``[x_j, v_j]`` of every slot at once (one
        random access per edge), subtract the agent's own into a slot-major buffer
        ``(2 dim, slots, block)`` so that every later operation runs over a contiguous run of
        agents, take the largest ``|x_j - x_i|`` and ``|v_j - v_i|`` for ``s_i``, write the rows
        (velocities times ``T``, all over ``max(s, tiny)`` when normalized) and the mask into a
        block buffer holding the clock, and copy it out at once. A handful of array operations
        per block (no per-block Python objects beyond a few views); the same operations per
        entry as the generic path, so the same values.
        """
        b, n = obs.shape[:2]
        T = clock.interval() if self.velocity_weight is None else self.velocity_weight  # the velocities' weight
        features = clock.per_instant(self.tables.features)
        pieces = graphs.blocks(graphs.graph, min(BLOCK_AGENTS, n))
        if self._buffers is None:
            self._buffers = {}
        scale = np.empty((b, n))
        for episode in range(b):
            source = state[episode].reshape(n, -1)  # [x, v] of every agent, side by side
            own = source.T[:, None, :]  # (2 dim, 1, N)
            for start, index, mask in pieces:
                m = index.shape[1]
                kernel = self._buffers.get(m)
                if kernel is None:
                    kernel = self._buffers[m] = _Block(m, self.layout, state.shape[-1])
                if kernel.instant != clock.k:  # the clock columns, written once per instant
                    kernel.clock[...] = features
                    kernel.instant = clock.k
                stop = start + m
                kernel.fill(source, index, own[:, :, start:stop], mask, T, self.normalized)
                scale[episode, start:stop] = kernel.scale
                obs[episode, start:stop, : self.layout.clock_end] = kernel.output
        return scale


class _Block:
    """Buffers and fixed views of :meth:`Observer._observe_blocked` for blocks of ``m`` agents (312 bytes an agent at 4 slots)."""

    def __init__(self, m: int, layout: Any, dim: int) -> None:
        width = 2 * dim
        self.gathered = np.empty((layout.slots, m, width))
        self.by_column = self.gathered.transpose(2, 0, 1)  # (2 dim, slots, m)
        self.difference = np.empty((width, layout.slots, m))
        self.absolute = np.empty_like(self.difference)
        self.largest = np.empty((2, m))
        self.scale = np.empty(m)
        self.floored = np.empty(m)
        self.output = np.empty((m, layout.clock_end))
        self.rows = self.output[:, : layout.rows_end].reshape(m, layout.slots, width).transpose(2, 1, 0)
        self.mask = self.output[:, layout.rows_end : layout.mask_end].T
        self.clock = self.output[:, layout.mask_end : layout.clock_end]
        self.dim = dim
        #: The instant whose clock features :attr:`clock` holds (-1: none yet).
        self.instant = -1

    def fill(self, source: Any, index: Any, own: Any, mask: Any, T: float, normalized: bool) -> None:
        """One block: :attr:`output` ``(m, clock_end)`` and :attr:`scale` ``(m,)`` from the gathered rows."""
        d = self.dim
        np.take(source, index, axis=0, out=self.gathered, mode="clip")
        np.subtract(self.by_column, own, out=self.difference)  # z_j - z_i, slot-major
        np.abs(self.difference, out=self.absolute)
        np.maximum.reduce(self.absolute[:d], axis=(0, 1), out=self.largest[0])
        np.maximum.reduce(self.absolute[d:], axis=(0, 1), out=self.largest[1])
        np.multiply(T, self.largest[1], out=self.scale)
        np.maximum(self.largest[0], self.scale, out=self.scale)  # s_i = max(|x_j - x_i|, T |v_j - v_i|) (T: weight)
        if normalized:
            np.maximum(self.scale, TINY, out=self.floored)
            velocities = self.difference[d:]
            np.multiply(velocities, T, out=velocities)  # the row factor of velocities (T_{k+1}, or T_s)
            np.divide(self.difference, self.floored, out=self.rows)
        else:
            np.copyto(self.rows, self.difference)
        np.copyto(self.mask, mask)


def normalized_state(
    state: Any, current_disagreement: Any, clock: Any, tables: Any, backend: Any, config: EnvConfig
) -> Any:
    """The scale-free global state of every episode, ``(B, N * n dim + 3)`` (see :meth:`ConsensusEngine.normalized_state`)."""
    xp = backend.xp
    components = [
        (config.settling_time**i) * (state[:, :, i] - xp.mean(state[:, :, i], axis=1, keepdims=True))
        for i in range(config.n_states)
    ]
    rows = _over_scale(xp.concat(components, axis=-1), xp.reshape(current_disagreement, (-1, 1)), backend)
    rows = xp.reshape(xp.clip(rows, -1.0, 1.0), (backend.n_episodes, -1))
    features = clock.per_instant(tables.features)
    features = xp.reshape(features, (-1, features.shape[-1])) + backend.zeros((backend.n_episodes, 1))
    return xp.concat([rows, features], axis=-1)
