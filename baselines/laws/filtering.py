"""A law for measurement noise: dead-beat factors on the free-motion predictions, each read by least squares.

Law, source, proven graph class and refusals: docs: optimality.md, "Filtered dead-beat (`filtering`)".

Every agent works on free-motion predictions ``p = (x + (T_s - t) v, v)``, which coasting leaves unchanged.
The episode is cut into blocks of ``block`` intervals. Within a block every agent coasts, so its aggregated
relative row ``r_i(t) = (1/(d_i+1)) Σ_j (z_j - z_i)`` is ``Ψ_t⁻¹ ρ_i`` with ``ρ_i`` (the aggregated relative
prediction) constant and ``Ψ_t⁻¹ = [[1, -(T_s - t)], [0, 1]]``: the agent estimates ``ρ_i`` by least squares
from every noisy row of the block (linear in its past readings). At the block's end it moves its own
prediction by ``G ρ̂_i`` (``G = I/μ`` for a real eigenvalue μ of ``(D + I)⁻¹ L``; ``R``, then ``Rᵀ`` over two
blocks for a complex pair, as in ``minimum_time``), spread over ``spread`` intervals with the least energy.
On predictions the factors commute with coasting, so any gap between them is harmless: in exact arithmetic
the law is exact after the factors, like ``minimum_time``, and under noise each factor reads an average of
``block - spread + 1`` rows instead of one. After the factors, ``damping`` blocks move the prediction by
``ρ̂_i / 2``: nothing once the agents agree, a damped average of what the factors' noise left otherwise.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws.minimum_time import (
    design_eigenvalues,
    leja_factors,
    refuse_what_a_graph_design_cannot_honour,
)
from fxc_env.baselines.laws.motion_signals import SignalPolicy, advance, refuse_unless_exact_raw_rows, steer_plan
from fxc_env.config import config_of
from fxc_env.core import validation
from fxc_env.core.validation import ArgumentError


def prediction_gains(eigenvalues: np.ndarray, settling_time: float) -> np.ndarray:
    """The gains ``(F, 2, 2)`` on predictions ``(p_x, p_v)``, one per block, in Leja order.

    A real eigenvalue μ gives ``I / μ``; a complex pair gives ``S⁻¹ R S`` then ``S⁻¹ Rᵀ S`` with
    ``R = [[a, -b], [b, a]]``, ``a + i b = μ / |μ|²`` and ``S = diag(1, T_s)`` (the velocity part as a second
    register in metres): ``(I - μ' Rᵀ)(I - μ' R) = (1 - μ'/μ)(1 - μ'/μ̄) I`` on every mode μ'.
    """
    gains = []
    for factor in leja_factors(eigenvalues):
        mu = factor.eigenvalue
        if factor.intervals == 1:
            gains.append(np.eye(2) / mu.real)
            continue
        a, b = mu.real / abs(mu) ** 2, mu.imag / abs(mu) ** 2
        gains.append(np.array([[a, -b * settling_time], [b / settling_time, a]]))
        gains.append(np.array([[a, b * settling_time], [-b / settling_time, a]]))
    return np.array(gains).reshape(-1, 2, 2)


#: Default move spread (intervals) and damping blocks, where K holds them (:func:`block_sizes`).
SPREAD, DAMPING = 4, 8


def block_sizes(
    n_factors: int, n_intervals: int, block: int | None, spread: int | None, damping: int | None
) -> tuple[int, int, int]:
    """``(block, spread, damping)`` in intervals, intervals and blocks: the given values, checked, or the defaults.

    Default ``spread``: :data:`SPREAD`, less where K cannot hold ``n_factors`` blocks of ``spread + 1`` intervals
    and a last move; default ``damping``: :data:`DAMPING`, fewer where K cannot hold them at that length; default
    ``block``: the longest that fits, ``(K - spread) // (n_factors + damping)``. Raises ArgumentError naming
    ``spread``, ``damping``, ``block`` or ``n_intervals`` (even one-interval moves do not fit).
    """
    K = n_intervals
    if spread is None:
        spread = max([s for s in range(1, SPREAD + 1) if n_factors * (s + 1) + s <= K], default=1)
    spread = validation.integer("spread", spread, 1)
    if damping is None:
        damping = min(DAMPING, max(0, (K - spread) // (spread + 1) - n_factors))
    damping = validation.integer("damping", damping, 0)
    n_blocks = n_factors + damping
    largest = (K - spread) // max(n_blocks, 1)
    if largest < spread + 1:
        raise ArgumentError(
            f"n_intervals: the filtering law needs {n_blocks} blocks of at least spread + 1 = {spread + 1} "
            f"intervals, then {spread} to move, at least {n_blocks * (spread + 1) + spread}; got {K}"
        )
    block = largest if block is None else validation.integer("block", block, spread + 1)
    if block > largest:
        raise ArgumentError(
            f"block: {n_blocks} blocks of {block} intervals and a last move of {spread} exceed K = {K}; "
            f"expected at most {largest}"
        )
    return block, spread, damping


class FilteringPolicy(SignalPolicy):
    """The filtered dead-beat law on the local observation: raw rows, ``plan`` or ``accel`` actions.

    It has memory (its own plans and the block's running sums), so it is called as
    :class:`~fxc_env.baselines.laws.motion_signals.SignalPolicy` says; agent i's action depends only on its own rows,
    the clock and its memory. Its one design input is the spectrum of ``(D + I)⁻¹ L``, which no relabelling of
    the agents changes.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` on a fixed digraph with a directed
            spanning tree, ideal double-integrator agents, ``obs_mode="raw"``, any schedule and ``obs_noise``.
        block: intervals per block (an int >= ``spread + 1``); None: the longest that fits,
            ``(K - spread) // (F + damping)``, F the blocks the factors need (``N - 1`` on a directed ring).
        spread: intervals over which each prediction move is spread (int >= 1; None: 4, or less where K is short):
            a longer move costs less energy and leaves fewer rows to read.
        damping: blocks after the factors that move the prediction by ``ρ̂_i / 2`` (int >= 0; None: 8, or fewer
            where K is short): they change nothing once the agents agree and average down what the factors' noise
            left (:func:`block_sizes`).

    Raises:
        ArgumentError: naming ``topology``, ``switching``, ``u_max``, ``link_dropout``, ``agent_model``,
            ``obs_mode``, ``action_mode``, ``n_intervals``, ``block``, ``spread`` or ``damping`` for what it
            cannot honour.
    """

    NAME: ClassVar[str] = "filtering"
    TITLE: ClassVar[str] = "the filtering law"
    LAW: ClassVar[str] = (
        "coast a block, estimate the aggregated relative prediction ρ_i by least squares over the block's rows, "
        "move the own prediction by G ρ̂_i (G = I/μ, or R then Rᵀ per complex pair of (D+I)⁻¹L, Leja order; "
        "then G = I/2 for the damping blocks)"
    )
    SOURCE: ClassVar[str] = "this project (least-squares filtered dead-beat factors on free-motion predictions)"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed digraph with a directed spanning tree, ideal agents: exact after the factors without noise; under "
        "noise each factor reads the mean of a block of rows"
    )

    def __init__(
        self, env: Any, block: int | None = None, spread: int | None = None, damping: int | None = None
    ) -> None:
        config = config_of(env, type(self).__name__)
        refuse_what_a_graph_design_cannot_honour(config, type(self).__name__, allow_noise=True)
        refuse_unless_exact_raw_rows(config, type(self).__name__)
        factors = prediction_gains(design_eigenvalues(config.topology), config.settling_time)
        self.block, self.spread, self.damping = block_sizes(len(factors), config.n_intervals, block, spread, damping)
        #: ``(F + damping, 2, 2)``: the gain on ``ρ̂_i`` of each block, the factors then ``I / 2``.
        self.gains = np.concatenate([factors, np.repeat(np.eye(2)[None] / 2.0, self.damping, axis=0)])
        super().__init__(config)

    # ------------------------------------------------------------------ schedule
    def _move_of(self, k: int) -> int | None:
        """The factor whose move starts at instant k, or None."""
        b, rest = divmod(k, self.block)
        return b - 1 if rest == 0 and 1 <= b <= len(self.gains) else None

    def _reads(self, k: int) -> bool:
        """Whether the row at instant k belongs to a block's estimate (nobody is moving at t_k)."""
        b, rest = divmod(k, self.block)
        return b < len(self.gains) + (rest == 0) and (b == 0 or rest == 0 or rest >= self.spread)

    # ------------------------------------------------------------------ memory
    def _reset(self, rows: np.ndarray, lead: tuple[int, ...]) -> None:
        shape = (*lead, 2, self.config.dim)
        self._memory = {"d": np.zeros(shape), "sums": np.zeros(shape), "goal": np.zeros(shape)}
        self._information = np.zeros((2, 2))

    def _plan(self, k: int, rows: np.ndarray, obs: np.ndarray) -> np.ndarray:
        memory = self._memory
        assert memory is not None
        _, mask, _ = self.layout.split(obs)
        t, settling = self._times[k], self.config.settling_time
        if self._reads(k):
            aggregated = np.sum(mask[..., None, None] * rows, axis=-3) / (np.sum(mask, axis=-1) + 1.0)[..., None, None]
            design = np.array([[1.0, -(settling - t)], [0.0, 1.0]])  # r = Ψ_t⁻¹ ρ
            memory["sums"] = memory["sums"] + np.einsum("ab,...ad->...bd", design, aggregated)
            self._information = self._information + design.T @ design
        factor = self._move_of(k)
        if factor is not None:
            estimate = np.einsum("ab,...bd->...ad", np.linalg.inv(self._information), memory["sums"])
            memory["goal"] = memory["goal"] + np.einsum("ab,...bd->...ad", self.gains[factor], estimate)
            memory["sums"], self._information = np.zeros_like(memory["sums"]), np.zeros((2, 2))
        moving = 1 <= k // self.block <= len(self.gains) and k % self.block < self.spread
        if moving:
            end = self._times[(k // self.block) * self.block + self.spread]
            goal = memory["goal"]  # the prediction change reached at `end`, as a deviation there
            deviation = np.stack([goal[..., 0, :] - (settling - end) * goal[..., 1, :], goal[..., 1, :]], axis=-2)
            plan = steer_plan(deviation, memory["d"], t, self._intervals[k], end)
        else:
            plan = np.zeros_like(memory["d"])
        memory["d"] = advance(memory["d"], plan, self._intervals[k])
        return plan

    def parameters(self) -> dict[str, float]:
        """The design: the blocks (factors), their length and the move's spread, in intervals."""
        return {
            "blocks": float(len(self.gains)),
            "damping": float(self.damping),
            "block": float(self.block),
            "spread": float(self.spread),
        }

    def guarantee(self) -> str:
        factors = len(self.gains) - self.damping
        return (
            f"exact in exact arithmetic after {factors} blocks of {self.block} intervals without noise; under "
            f"obs_noise each factor reads the least-squares mean of {self.block - self.spread + 1} rows"
        )
