"""Prescribed-time consensus with a gain that grows as ``1 / (T_s - t)`` (Wang, Song, Hill & Krstic 2019 family).

Law, source, proven graph class and refusals: docs: optimality.md, "Prescribed time (`prescribed_time`)".
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws import design
from fxc_env.baselines.laws.finite_time import is_undirected
from fxc_env.baselines.laws.policy import LinearRowPolicy
from fxc_env.core import validation

#: Largest ratio of the sampling period to the fastest closed-loop time constant at the cut-off.
HOLD_RESOLUTION = 0.2

#: Largest decay exponent p: the gains grow like p² (complete N = 6, K = 200 uniform: D(T_s)/D(0) = 1.4e-3 at
#: p = 3, 1.6e-16 at 100); at p = 1e4 a held step overflows float64 (directed ring of 6).
MAX_EXPONENT = 100.0


class PrescribedTimePolicy(LinearRowPolicy):
    """``u_i = sum_j [k_x (x_j - x_i) / sigma^2 + k_v (v_j - v_i) / sigma]``, ``sigma = max(T_s - t_k, delta)``.

    Args:
        env: an fxc_env environment or config (``action_mode="accel"``).
        exponent: p, ``1 < p <= 100`` (:data:`MAX_EXPONENT`), the decay exponent ``(T_s - t)^p`` of the slowest mode.
        cutoff: delta in seconds, ``0 < delta < T_s``; None uses ``max(2 h, 5 h k_v max|lambda|)`` with h the
            schedule's longest interval (at most T_s: then the gain is frozen throughout, :meth:`guarantee` says so).
    """

    NAME: ClassVar[str] = "prescribed_time"
    LAW: ClassVar[str] = (
        "u_i = -Σ_j a_ij [k_x (x_i - x_j)/σ² + k_v (v_i - v_j)/σ], σ = max(T_s - t, δ) (gain frozen at δ), ZOH"
    )
    SOURCE: ClassVar[str] = "Wang, Song, Hill & Krstic 2019 family (time-varying gain T_s/(T_s - t))"
    GRAPH_CLASS: ClassVar[str] = "undirected connected graphs (digraphs: unproven; mode exponents checked)"

    def __init__(self, env: Any, exponent: float = 3.0, cutoff: float | None = None) -> None:
        super().__init__(env)
        self.exponent = validation.in_range(
            "exponent",
            exponent,
            1.0,
            MAX_EXPONENT,
            low_open=True,
            below="at p <= 1 the slowest mode does not reach zero by T_s",
            above=f"above {MAX_EXPONENT:g} the gains (like p²) leave what a held step keeps in float64",
        )
        settling_time = self.config.settling_time
        if cutoff is not None:
            cutoff = validation.in_range(
                "cutoff", cutoff, 0.0, settling_time, low_open=True, high_open=True, above="T_s is the deadline (s)"
            )
        eigenvalues = design.design_eigenvalues(self.config.topology)
        slowest = float(np.min(eigenvalues.real))
        self.velocity_gain = 2.0 * self.exponent / slowest
        self.position_gain = self.exponent * (self.exponent + 1.0) / slowest
        h = float(self.config.schedule.intervals.max())
        automatic = max(2.0 * h, h * self.velocity_gain * float(np.max(np.abs(eigenvalues))) / HOLD_RESOLUTION)
        self.cutoff = min(automatic, settling_time) if cutoff is None else float(cutoff)
        # Mode exponents r of every eigenvalue: roots of r^2 - (1 + lambda k_v) r + lambda k_x.
        b = 1.0 + eigenvalues * self.velocity_gain
        root = np.sqrt(b * b - 4.0 * eigenvalues * self.position_gain + 0j)
        self.mode_exponent = float(np.min(np.minimum(((b - root) / 2).real, ((b + root) / 2).real)))

    def row_gains(self, clock: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t, _ = self.time_features(clock)
        sigma = np.maximum(self.config.settling_time - t, self.cutoff)
        return self.position_gain / (sigma * sigma), self.velocity_gain / sigma

    def parameters(self) -> dict[str, float]:
        return {
            "p": self.exponent,
            "k_x": self.position_gain,
            "k_v": self.velocity_gain,
            "cutoff_s": self.cutoff,
            "min_mode_exponent": self.mode_exponent,
        }

    def guarantee(self) -> str:
        frozen = self.cutoff >= self.config.settling_time
        if frozen:
            return (
                f"no prescribed-time decay: the cut-off reaches T_s = {self.config.settling_time:g} s, so the gains "
                "are frozen throughout (a linear law with constant gains; a shorter hold or a smaller exponent helps)"
            )
        if is_undirected(self.config.topology) and self.config.topology.period == 1:
            return "proven: undirected connected graph"
        return f"unproven: directed or switching graph (least mode exponent Re r = {self.mode_exponent:.3g})"
