"""Sampling schedules: the instants ``0 = t_0 < t_1 < ... < t_K = T_s``.

The paper (Section 3) uses ``T_k = 6 T_s / (pi k)^2``, ``k = 1, 2, ...``, whose infinite sum
is exactly ``T_s``: infinitely many samples accumulate at the deadline. A simulation has K
intervals, so we take ``T_1 .. T_{K-1}`` from the schedule and let the last interval end
**exactly** at ``T_s`` (``T_K = T_s - t_{K-1}``). The deadline is then reached in K
steps and the disagreement left at ``T_s`` is the honest figure of merit.

Do not replace the paper's schedule by a geometric one (``T_s / 2^k``): the controller's
gains grow like ``1 / T_k^3`` and its inputs then diverge (1e31 by k = 60 on a ring).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.core import validation

SCHEDULE_NAMES = ("paper", "uniform")


@dataclass(frozen=True, eq=False)
class Schedule:
    """Sampling instants of one episode.

    Attributes:
        times: ``(K + 1,)`` instants in seconds, ``times[0] = 0`` and ``times[-1] = T_s`` exactly.
        intervals: ``(K,)`` interval lengths ``T_{k+1} = t_{k+1} - t_k`` in seconds, all > 0.
        name: ``"paper"``, ``"uniform"`` or ``"custom"``.
    """

    times: np.ndarray
    intervals: np.ndarray
    name: str

    @property
    def settling_time(self) -> float:
        """``T_s`` in seconds."""
        return float(self.times[-1])

    @property
    def n_intervals(self) -> int:
        """K, the number of sampling intervals (communication rounds)."""
        return len(self.intervals)


def _validated_n_intervals(n_intervals: Any) -> int:
    return validation.integer("n_intervals", n_intervals, 1, validation.MAX_INTERVALS)


def paper_interval(k: np.ndarray | int, settling_time: float) -> np.ndarray:
    """The paper's ``T_k = 6 T_s / (pi k)^2`` for ``k >= 1`` (seconds)."""
    k = np.asarray(k, dtype=float)
    return 6.0 * settling_time / (np.pi * k) ** 2


def make_schedule(settling_time: Any = 20.0, n_intervals: Any = 200, schedule: Any = "paper") -> Schedule:
    """Build the K sampling intervals ending exactly at ``settling_time``.

    Args:
        settling_time: ``T_s`` in seconds, in ``(0, 1e30]``.
        n_intervals: K >= 1. Ignored (may be ``None``) when ``schedule`` is an array.
        schedule: ``"paper"`` (``6 T_s / (pi k)^2``, last interval closes at ``T_s``),
            ``"uniform"`` (``T_s / K``), or an array of K positive interval lengths in
            seconds that sum to ``T_s`` (relative tolerance 1e-9).

    Every interval must be at least 1e-30 s long (the float64 range of
    :mod:`fxc_env.core.validation`).

    Raises:
        ArgumentError / ArgumentTypeError naming the argument.
    """
    t_s = validation.real("settling_time", settling_time, maximum=validation.MAX_SETTLING_TIME, positive=True)
    if isinstance(schedule, str):
        if schedule not in SCHEDULE_NAMES:
            raise validation.ArgumentError(
                f"schedule: unknown name {schedule!r}; expected one of {SCHEDULE_NAMES} or an array"
            )
        k_total = _validated_n_intervals(n_intervals)
        if schedule == "paper":
            # t_k = T_s (6/pi^2) sum_{j<=k} 1/j^2 < T_s for k <= K-1; t_K = T_s exactly.
            inner = np.cumsum(paper_interval(np.arange(1, k_total), t_s))
        else:
            inner = t_s * np.arange(1, k_total) / k_total
        times = np.concatenate(([0.0], inner, [t_s]))
        name = schedule
    else:
        times, name = _given_times(schedule, n_intervals, t_s), "custom"
    intervals = np.diff(times)
    if np.any(intervals < validation.MIN_INTERVAL * (1 - 1e-9)):  # rounding of the times is not a shorter interval
        if name == "custom":  # every given length passed the check: summing into times lost one
            raise validation.ArgumentError(
                f"schedule: interval {int(intervals.argmin())} is lost to float64 rounding once the lengths are "
                f"summed into sampling times (it is {intervals.min():g} s next to t = {times[intervals.argmin()]:g} "
                f"s); expected every interval >= {validation.MIN_INTERVAL:g} s relative to t"
            )
        raise validation.ArgumentError(
            f"n_intervals: {len(intervals)} intervals over settling_time = {t_s!r} s leave an interval of "
            f"{intervals.min():g} s; expected every interval >= {validation.MIN_INTERVAL:g} s (float64 range)"
        )
    times.setflags(write=False)
    intervals.setflags(write=False)
    return Schedule(times=times, intervals=intervals, name=name)


def _given_times(schedule: Any, n_intervals: Any, t_s: float) -> np.ndarray:
    """The sampling times ``(K + 1,)`` of given interval lengths, checked against ``n_intervals`` and ``T_s``."""
    lengths = validation.interval_lengths("schedule", schedule)
    if lengths.size > validation.MAX_INTERVALS:
        raise validation.ArgumentError(
            f"schedule: expected at most {validation.MAX_INTERVALS} intervals, got {lengths.size}"
        )
    if n_intervals is not None and _validated_n_intervals(n_intervals) != lengths.size:
        raise validation.ArgumentError(f"schedule: has {lengths.size} intervals but n_intervals = {n_intervals}")
    total = math.fsum(lengths)
    if abs(total - t_s) > 1e-9 * t_s:
        raise validation.ArgumentError(
            f"schedule: interval lengths sum to {total!r} s, expected settling_time = {t_s!r} s"
        )
    return np.concatenate(([0.0], np.cumsum(lengths[:-1]), [t_s]))
