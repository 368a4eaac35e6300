"""The engine's clock: which sampling instant ``t_k`` each episode is at.

Episodes start together and advance in lock step (:class:`LockStepClock`: one host counter
``k``) until a partial reset restarts some of them; from then on every episode has its own
instant (:class:`EpisodeClock`: ``steps`` ``(B,)`` on the device) and the interval length,
the clock features and the graph are gathered per episode. The engine swaps one clock for
the other at the first partial reset; neither branches on the other's case.

Both read the per-instant tables of :class:`InstantTables` (built once per engine): the
interval lengths ``T_{k+1} = t_{k+1} - t_k`` of the schedule (paper Section 3), the clock
features of the observation (``t_k / T_s, T_{k+1} / T_s, k / K``), and the factors that put
a state component in position units (docs: agent-models.md, "Agent models and formations").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.arrays import namespace


class InstantTables:
    """What depends on the instant k only, for ``k = 0 .. K`` (the instant K repeats the last interval).

    Attributes:
        times: ``t_k`` in seconds, ``(K + 1,)`` numpy (``times[K] = T_s`` exactly).
        next_interval: ``T_{k+1}`` in seconds, a list of K + 1 floats (host).
        next_interval_array: the same ``(K + 1,)`` on the backend.
        features: ``t_k / T_s, T_{k+1} / T_s, k / K`` per instant, ``(K + 1, 3)``.
        row_factors: what each flat observation row entry is multiplied by before the
            division by the local scale: 1 for positions, ``T_{k+1}`` for velocities,
            ``(K + 1, slots * n * dim)``.
        row_scales: per instant, what each state component is multiplied by to read in
            position units, ``(K + 1, n)``.
        residual_factors: per instant, what a normalized ``action_mode="residual"`` correction
            is multiplied by to read in the plan's units: 1 for ``alpha_x``, ``T_{k+1} / T_s``
            for ``alpha_v`` (its velocity correction is ``s alpha_v / T_s``), ``(K + 1, 2 dim)``.
    """

    def __init__(self, config: EnvConfig, backend: Any) -> None:
        schedule = config.schedule
        self.n_intervals = schedule.n_intervals
        self.times = schedule.times
        k_all = np.arange(schedule.n_intervals + 1)
        next_interval = schedule.intervals[np.minimum(k_all, schedule.n_intervals - 1)]
        features = np.stack([schedule.times, next_interval, 0 * k_all], axis=1) / schedule.settling_time
        features[:, 2] = k_all / schedule.n_intervals
        self.next_interval = next_interval.tolist()
        self.next_interval_array = backend.array(next_interval)
        self.features = backend.array(features)
        per_row = np.repeat(config.row_scales, config.dim, axis=1)
        self.row_factors = backend.array(np.tile(per_row, config.layout.slots))
        self.row_scales = backend.array(config.row_scales)
        per_part = np.stack([np.ones(schedule.n_intervals + 1), features[:, 1]], axis=1)
        self.residual_factors = backend.array(np.repeat(per_part, config.dim, axis=1))


class LockStepClock:
    """Every episode at the same instant ``k`` (a host integer): per-instant values are table rows.

    Args:
        tables: the engine's :class:`InstantTables`.
        k: the starting instant.
    """

    per_episode = False

    def __init__(self, tables: InstantTables, k: int = 0) -> None:
        self.tables = tables
        self.k = k

    @property
    def steps(self) -> None:
        """No per-episode instants in lock step."""
        return None

    @property
    def done(self) -> bool:
        """The deadline has been reached: ``t_k = T_s``."""
        return self.k >= self.tables.n_intervals

    @property
    def time(self) -> float:
        """``t_k`` in seconds."""
        return float(self.tables.times[self.k])

    def interval(self, trailing: int = 0) -> float:
        """``T_{k+1}`` in seconds, a number (``trailing`` is for :class:`EpisodeClock`'s shape)."""
        return self.tables.next_interval[self.k]

    def per_instant(self, table: Any) -> Any:
        """Row ``k`` of a ``(K + 1, F)`` table: ``(F,)``."""
        return table[self.k]

    def episode_steps(self, backend: Any) -> Any:
        """Each episode's instant ``(B,)`` on the device (all ``k``)."""
        xp = backend.xp
        return xp.full((backend.n_episodes,), self.k, dtype=xp.int64, device=backend.device)

    def check_can_step(self) -> None:
        """Refuse a step past ``T_s`` at once, on the host."""
        if self.done:
            raise RuntimeError("step: the episode reached T_s; reset before stepping again")

    def past_deadline(self) -> None:
        """Lock step refuses a step past ``T_s`` in :meth:`check_can_step`: nothing to flag."""
        return None

    def advance(self) -> int:
        """Move to ``t_{k+1}``; returns the instant reached."""
        self.k += 1
        return self.k


class EpisodeClock:
    """Each episode at its own instant ``steps`` ``(B,)`` (int64 on the device), after a partial reset.

    Args:
        tables: the engine's :class:`InstantTables`.
        steps: each episode's instant ``(B,)``.
        k: the lock-step instant when the clocks parted (kept for :attr:`ConsensusEngine.k`).
    """

    per_episode = True

    def __init__(self, tables: InstantTables, steps: Any, k: int) -> None:
        self.tables = tables
        self.steps = steps
        self.k = k

    @property
    def done(self) -> bool:
        raise RuntimeError("done: episodes keep their own clocks since a partial reset; use episode_done()")

    @property
    def time(self) -> float:
        """The lock-step ``t_k`` when the clocks parted, in seconds (see :attr:`steps` for each episode's)."""
        return float(self.tables.times[self.k])

    def interval(self, trailing: int = 0) -> Any:
        """Each episode's ``T_{k+1}`` in seconds, ``(B,)`` followed by ``trailing`` axes of 1."""
        xp = namespace(self.steps)
        lengths = xp.take(self.tables.next_interval_array, self.steps, axis=0)
        return xp.reshape(lengths, (-1,) + (1,) * trailing)

    def per_instant(self, table: Any) -> Any:
        """Each episode's row of a ``(K + 1, F)`` table: ``(B, 1, F)``."""
        return namespace(self.steps).take(table, self.steps, axis=0)[:, None, :]

    def episode_steps(self, backend: Any) -> Any:
        return self.steps

    def check_can_step(self) -> None:
        """Nothing on the host: :meth:`past_deadline` flags such episodes on the device."""

    def past_deadline(self) -> Any:
        """``(B,)``: the episodes already at ``T_s`` (stepping them is flagged, never waited on)."""
        return self.steps >= self.tables.n_intervals

    def advance(self) -> Any:
        """Move every episode to its next instant (held at K); returns the instants reached ``(B,)``."""
        xp = namespace(self.steps)
        self.steps = xp.minimum(self.steps + 1, xp.full_like(self.steps, self.tables.n_intervals))
        return self.steps


class BeforeReset(LockStepClock):
    """The clock of an engine that was never reset: instant 0 of a zero state, which :meth:`ConsensusEngine.step` refuses
    (a ``RuntimeError``, as the environments' ``step`` before ``reset``); the first reset replaces it."""

    def check_can_step(self) -> None:
        raise RuntimeError("step: call reset() before the first step (the engine holds no episode yet)")
