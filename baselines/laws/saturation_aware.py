"""A saturation-aware law: the paper's plan where it fits under the input limit, a held linear law where it does not.

Law, on each interval of a uniform schedule (``T = T_s / K``): agent i forms the paper's minimum-energy plan
(eq. 11) to the average of the coasted states of itself and its in-neighbours. If the plan's input at both ends
lies within ``±u_max`` it applies it (the reference's exact averaging step); otherwise it holds

    u_i = g sum_j a_ij [(x_j - x_i) + gamma (v_j - v_i)]

(clipped by the actuator if need be) until the next sample. ``u_max`` is read from the observation's
input-limit entry ``l / (1 + |l|)``, ``l = log10(u_max T^2 / s_i)``; without a limit the law is the reference.

Parameters: ``gain`` g = 1 s^-2 and ``gamma`` = 3 s (a scan on ``paper_fig1`` and a random N = 20 digraph at
``u_max`` 10 and 100). No proof: a heuristic of this project (docs: training.md, "Training learned policies").
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws.policy import HoldPolicy, law_gain
from fxc_env.config import config_of
from fxc_env.core.dynamics import input_from_plan
from fxc_env.core.validation import ArgumentError


def neighbourhood_sums(rows: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sums of the real rows' position and velocity parts ``(..., dim)`` each, and ``1 / (d_i + 1)`` ``(..., 1)``."""
    real_rows = mask[..., None]
    sum_x = np.sum(real_rows * rows[..., 0, :], axis=-2)
    sum_v = np.sum(real_rows * rows[..., 1, :], axis=-2)
    return sum_x, sum_v, 1.0 / (np.sum(mask, axis=-1, keepdims=True) + 1.0)


class SaturationAwarePolicy(HoldPolicy):
    """The paper's plan where it fits under ``u_max``, else a held linear consensus input.

    Args:
        env: an fxc_env environment or config (``accel`` actions on raw rows, or ``plan`` on normalized rows).
        gain, gamma: the held linear law's ``g`` (1/s²) and ``γ`` (s), each ``0 < value <= 1e12``
            (:data:`~fxc_env.baselines.laws.policy.MAX_GAIN`).
    """

    NAME: ClassVar[str] = "saturation_aware"
    LAW: ClassVar[str] = (
        "eq. (11)'s plan if both ends fit in ±u_max, else u_i = g Σ_j a_ij [(x_j - x_i) + γ (v_j - v_i)] held"
    )
    SOURCE: ClassVar[str] = "this project (a heuristic: the reference where it fits, Ren & Atkins 2007's law where not)"
    GRAPH_CLASS: ClassVar[str] = "none proven"

    #: Besides its benchmark setting (accel actions, raw rows) it acts in the learned
    #: policies' units (plan actions, normalized rows), as a teacher for imitation.
    OBS_MODES: ClassVar[tuple[str, ...]] = ("raw", "normalized")

    def __init__(self, env: Any, gain: float = 1.0, gamma: float = 3.0) -> None:
        config = config_of(env, type(self).__name__)
        self.planning = (config.action_mode, config.obs_mode) == ("plan", "normalized")
        if not self.planning:
            super().__init__(env)  # checks accel actions and raw rows
        else:
            self.config, self.layout = config, config.layout
        if config.obs_mode == "normalized" and not self.planning:
            raise ArgumentError("obs_mode: SaturationAwarePolicy reads normalized rows with plan actions only")
        self.gain = law_gain("gain", gain, "1/s²")
        self.gamma = law_gain("gamma", gamma, "s")

    def parameters(self) -> dict[str, float]:
        return {"gain": self.gain, "gamma": self.gamma}

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self.planning:
            return self.act_in_plan_units(obs)
        layout = self.layout
        rows, mask, clock = layout.split(obs)
        sum_dx, sum_dv, weight = neighbourhood_sums(rows, mask)
        _, T = self.time_features(clock)
        u_start, u_end = input_from_plan(weight * (sum_dx + T * sum_dv), weight * sum_dv, T)
        if not layout.limit_feature:
            return np.concatenate([u_start, u_end], axis=-1)
        u_max = self.input_limit(obs, rows, T)
        fits = np.all(np.maximum(np.abs(u_start), np.abs(u_end)) <= u_max, axis=-1, keepdims=True)
        held = self.gain * (sum_dx + self.gamma * sum_dv)
        return np.concatenate([np.where(fits, u_start, held), np.where(fits, u_end, held)], axis=-1)

    def act_in_plan_units(self, obs: np.ndarray) -> np.ndarray:
        """The same law as plan actions on normalized rows ``r_x = dx / s``, ``r_v = T dv / s``.

        The plan ``alpha`` fits where ``(6 alpha_x - 2 alpha_v, 4 alpha_v - 6 alpha_x)`` is within
        ``rho = u_max T^2 / s`` (from the limit entry); the held input is ``alpha = g T^2 (S_x + (gamma / T) S_v) (1/2, 1)``.
        """
        layout = self.layout
        rows, mask, clock = layout.split(obs)
        sum_x, sum_v, weight = neighbourhood_sums(rows, mask)
        plan_x, plan_v = weight * (sum_x + sum_v), weight * sum_v
        plan = np.concatenate([plan_x, plan_v], axis=-1)
        if not layout.limit_feature:
            return plan
        _, T = self.time_features(clock)
        feature = obs[..., layout.clock_end : layout.clock_end + 1]
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            rho = np.where(np.abs(feature) < 1.0, 10.0 ** (feature / (1.0 - np.abs(feature))), np.inf)
        need = np.maximum(np.abs(6 * plan_x - 2 * plan_v), np.abs(4 * plan_v - 6 * plan_x))
        fits = np.all(need <= rho, axis=-1, keepdims=True)
        held = self.gain * T * T * (sum_x + (self.gamma / T) * sum_v)
        return np.where(fits, plan, np.concatenate([held / 2, held], axis=-1))

    def input_limit(self, obs: np.ndarray, rows: np.ndarray, T: np.ndarray) -> np.ndarray:
        """``u_max`` (m/s^2, ``(..., 1)``) recovered from the limit entry and the agent's scale ``s_i``."""
        feature = obs[..., self.layout.clock_end : self.layout.clock_end + 1]
        scale = np.maximum(
            np.max(np.abs(rows[..., 0, :]), axis=(-2, -1)), np.max(np.abs(rows[..., 1, :]), axis=(-2, -1)) * T[..., 0]
        )
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            decades = feature / (1.0 - np.abs(feature))
            return np.where(np.abs(feature) < 1.0, 10.0**decades * scale[..., None] / (T * T), np.inf)
