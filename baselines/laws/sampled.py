"""Sampled-data linear consensus (Cao & Ren 2010): the linear law held over a uniform period.

Law: the linear law of :mod:`fxc_env.baselines.laws.linear`, measured at the sampling instants and held for
``h = T_s / K``::

    u_i(t) = -g sum_j a_ij [(x_i(t_k) - x_j(t_k)) + gamma (v_i(t_k) - v_j(t_k))],  t in [t_k, t_k + h)

- Source: Y. Cao and W. Ren, "Sampled-data discrete-time coordination algorithms for
  double-integrator dynamics under dynamic directed interaction", Int. J. Control 83 (2010).
- Proven graph class: fixed or periodically switching digraphs whose union has a directed spanning tree, for
  ``(g, gamma, h)`` whose exact one-sample map is a contraction (:func:`fxc_env.baselines.laws.design.zoh_radius`).
- Parameters: ``gain`` ``g`` (1/s^2), ``gamma`` (s), designed offline for the sampling period
  (:func:`fxc_env.baselines.laws.design.design_sampled_gains`). It runs with the reference's K.
"""

from __future__ import annotations

from typing import Any, ClassVar

from fxc_env.baselines.laws import design
from fxc_env.baselines.laws.linear import LinearConsensusPolicy
from fxc_env.core.validation import ArgumentError


class SampledLinearPolicy(LinearConsensusPolicy):
    """The linear law with gains designed for the schedule's sampling period (Cao & Ren 2010).

    Args:
        env: an fxc_env environment or config, ``action_mode="accel"``; its schedule's longest
            interval is the sampling period h the design uses (``T_s / K`` when uniform).
        gamma, gain: explicit gains (``γ`` in s, ``g`` in 1/s², each ``0 < value <= 1e12``,
            :data:`~fxc_env.baselines.laws.policy.MAX_GAIN`); both None (the default) designs both for h. A ``gain``
            without ``gamma`` is refused by name: the design chooses the gain too, so it would be ignored.
    """

    NAME: ClassVar[str] = "linear_sampled"
    LAW: ClassVar[str] = "u_i = -g Σ_j a_ij [(x_i - x_j) + γ (v_i - v_j)] at t_k, held for h = T_s/K"
    SOURCE: ClassVar[str] = "Cao & Ren 2010 (sampled-data, zero-order hold)"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed or periodically switching digraphs with a jointly spanning tree, iff the exact ZOH map contracts"
    )

    def __init__(self, env: Any, gamma: float | None = None, gain: float | None = None) -> None:
        if gamma is None and gain is not None:
            raise ArgumentError(
                f"gain: {type(self).__name__} designs the gain with gamma for the sampling period; give gamma too "
                f"to run an explicit gain, got gain={gain!r} without gamma"
            )
        self.radius = float("nan")
        super().__init__(env, gamma=gamma, gain=1.0 if gain is None else gain)

    @property
    def sampling_period(self) -> float:
        """h in seconds: the longest interval of the schedule."""
        return float(self.config.schedule.intervals.max())

    def _design(self) -> None:
        h = self.sampling_period
        if self._gamma is None:
            self.gain, self.gamma, self.radius = design.design_sampled_gains(self.config.topology, h)
        else:
            self.gamma = self._gamma
            self.radius = design.zoh_radius(self.config.topology, self.gamma, self.gain, h)

    def parameters(self) -> dict[str, float]:
        return {"gain": self.gain, "gamma": self.gamma, "h": self.sampling_period, "zoh_radius": self.radius}

    def guarantee(self) -> str:
        if self.radius < 1.0:
            return f"proven: exact ZOH map contracts (asymptotic radius {self.radius:.4f} per sample)"
        return f"no stable gains found (radius {self.radius:.4f} per sample)"
