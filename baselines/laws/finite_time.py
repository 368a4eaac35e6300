"""Finite-time second-order consensus (Wang & Hong 2008 family).

Law (componentwise, ``sig(z)^a = sign(z) |z|^a``)::

    u_i = -g sum_j a_ij [sig(x_i - x_j)^a1 + sig(v_i - v_j)^a2],   a2 = 2 a1 / (1 + a1)

- Source: X. Wang and Y. Hong, "Finite-time consensus for multi-agent networks with
  second-order agent dynamics", Proc. 17th IFAC World Congress (2008).
- Proven graph class: **undirected** connected graphs; the benchmark runs it on directed ones **unproven**.
- Parameters: ``alpha`` = a1 in (0, 1) [0.5, so a2 = 2/3], ``gain`` g [1, SI units: not homogeneous, so its
  speed depends on the scale of the state]; ``obs_mode="raw"`` only. A continuous-measurement law: the
  benchmark runs it on a fine ``uniform`` schedule with a zero-order hold.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws.policy import HoldPolicy, law_gain
from fxc_env.core import validation


def sig(z: np.ndarray, power: float) -> np.ndarray:
    """``sign(z) |z|^power`` elementwise."""
    return np.sign(z) * np.abs(z) ** power


def is_undirected(topology: Any) -> bool:
    """Every graph of the period is symmetric (each edge ``(j, i)`` has its ``(i, j)``)."""
    return all((adjacency != adjacency.T).nnz == 0 for adjacency in map(topology.adjacency, range(topology.period)))


class FiniteTimePolicy(HoldPolicy):
    """``u_i = -g sum_j a_ij [sig(x_i - x_j)^a1 + sig(v_i - v_j)^a2]`` held over each interval.

    Args:
        env: an fxc_env environment or config (``action_mode="accel"``, ``obs_mode="raw"``).
        alpha: a1, ``0 < a1 < 1`` (the theorem's range: a1 = 1 is the linear law, which converges only
            asymptotically); a2 = 2 a1 / (1 + a1).
        gain: g in 1/s², ``0 < g <= 1e12`` (:data:`~fxc_env.baselines.laws.policy.MAX_GAIN`).
    """

    NAME: ClassVar[str] = "finite_time"
    LAW: ClassVar[str] = "u_i = -g Σ_j a_ij [sig(x_i - x_j)^a1 + sig(v_i - v_j)^a2], a2 = 2a1/(1+a1), ZOH"
    SOURCE: ClassVar[str] = "Wang & Hong 2008 family"
    GRAPH_CLASS: ClassVar[str] = "undirected connected graphs (digraphs: unproven)"

    def __init__(self, env: Any, alpha: float = 0.5, gain: float = 1.0) -> None:
        super().__init__(env)
        self.alpha = validation.in_range(
            "alpha",
            alpha,
            0.0,
            1.0,
            low_open=True,
            high_open=True,
            below="the theorem's exponents are positive",
            above="at 1 the law is linear and converges only asymptotically, above it is not the theorem's law",
        )
        self.alpha_velocity = 2.0 * self.alpha / (1.0 + self.alpha)
        self.gain = law_gain("gain", gain, "1/s²")

    def input(self, dx: np.ndarray, dv: np.ndarray, mask: np.ndarray, clock: np.ndarray) -> np.ndarray:
        # Rows hold x_j - x_i; sig is odd, so -sig(x_i - x_j) = sig(x_j - x_i). Padded rows are 0.
        terms = sig(dx, self.alpha) + sig(dv, self.alpha_velocity)
        return self.gain * np.sum(mask[..., None] * terms, axis=-2)

    def parameters(self) -> dict[str, float]:
        return {"gain": self.gain, "a1": self.alpha, "a2": self.alpha_velocity}

    def guarantee(self) -> str:
        if is_undirected(self.config.topology) and self.config.topology.period == 1:
            return (
                "proven in continuous time: undirected connected graph (held over the schedule's intervals: "
                "unproven, a large gain diverges)"
            )
        return "unproven: directed or switching graph"
