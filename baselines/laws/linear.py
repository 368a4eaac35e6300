"""Linear second-order consensus (Ren & Atkins 2007), with Yu, Chen & Cao's exact gain test.

Law (agent i, in-neighbours j, ``a_ij = 1``)::

    u_i = -g sum_j a_ij [(x_i - x_j) + gamma (v_i - v_j)]

- Source: W. Ren and E. Atkins, "Distributed multi-vehicle coordinated control via local
  information exchange", Int. J. Robust Nonlinear Control 17 (2007) (there ``g = 1``).
- Proven graph class: a fixed digraph with a directed spanning tree, **iff**
  ``gamma^2 > max Im(mu)^2 / (Re(mu) |mu|^2)`` over the nonzero eigenvalues ``mu`` of ``g L``
  (W. Yu, G. Chen and M. Cao, Automatica 46 (2010)); on an undirected graph any ``gamma > 0``.
- Parameters: ``gain`` ``g`` [1, 1/s^2], ``gamma`` [s], by default designed offline for the fastest decay
  (:func:`fxc_env.baselines.laws.design.design_gamma`; a switching period on its average Laplacian, not covered by
  the theorem). An explicit ``gamma`` is used as given (:attr:`passes_gain_test`).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws import design
from fxc_env.baselines.laws.policy import LinearRowPolicy, law_gain


class LinearConsensusPolicy(LinearRowPolicy):
    """``u_i = -g sum_j a_ij [(x_i - x_j) + gamma (v_i - v_j)]`` held over each interval.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` (``action_mode="accel"``,
            ``obs_mode`` ``"raw"`` or ``"normalized"``).
        gamma: velocity-to-position weight in seconds, ``0 < γ <= 1e12`` (:data:`~fxc_env.baselines.laws.policy.MAX_GAIN`);
            None designs it from the graph.
        gain: overall gain ``g`` in 1/s^2, ``0 < g <= 1e12``.
    """

    NAME: ClassVar[str] = "linear"
    LAW: ClassVar[str] = "u_i = -g Σ_j a_ij [(x_i - x_j) + γ (v_i - v_j)], zero-order hold at every sample"
    SOURCE: ClassVar[str] = "Ren & Atkins 2007; exact gain test Yu, Chen & Cao 2010"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed digraph with a directed spanning tree, iff γ² > max Im(μ)²/(Re(μ)|μ|²) (any γ > 0 if undirected)"
    )

    def __init__(self, env: Any, gamma: float | None = None, gain: float = 1.0) -> None:
        super().__init__(env)
        self.gain = law_gain("gain", gain, "1/s²")
        self._gamma = None if gamma is None else law_gain("gamma", gamma, "s")
        self._eigenvalues: np.ndarray | None = None
        self._design()

    # ----------------------------------------------------------------- design
    def _design(self) -> None:
        self.gamma = design.design_gamma(self.eigenvalues, self.gain) if self._gamma is None else self._gamma

    @property
    def eigenvalues(self) -> np.ndarray:
        """Nonzero eigenvalues of the (period-average) Laplacian the design uses, ``(N-1,)`` complex."""
        if self._eigenvalues is None:
            self._eigenvalues = design.design_eigenvalues(self.config.topology)
        return self._eigenvalues

    @property
    def gain_test_bound(self) -> float:
        """Yu, Chen & Cao's least gamma for this graph and gain (seconds)."""
        return design.gain_test_bound(self.eigenvalues, self.gain)

    @property
    def passes_gain_test(self) -> bool:
        """Whether ``gamma`` passes the exact continuous-time test."""
        return self.gamma > self.gain_test_bound

    # -------------------------------------------------------------------- law
    def row_gains(self, clock: np.ndarray) -> tuple[float, float]:
        return self.gain, self.gain * self.gamma

    def parameters(self) -> dict[str, float]:
        return {
            "gain": self.gain,
            "gamma": self.gamma,
            "gamma_min": self.gain_test_bound,
            "decay_rate": float(design.continuous_decay_rate(self.eigenvalues, self.gamma, self.gain)),
        }

    def guarantee(self) -> str:
        """Whether the run is covered by the theorem."""
        if self.config.topology.period > 1:
            verdict = "passes" if self.passes_gain_test else "fails"
            return f"unproven: switching graphs (average Laplacian {verdict} the gain test)"
        if self.passes_gain_test:
            return (
                "proven in continuous time: gain test passes (held over the schedule's intervals the exact ZOH map "
                "decides: linear_sampled's test; a large gain diverges)"
            )
        return "fails the gain test (diverges or oscillates)"
