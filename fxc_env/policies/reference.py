"""The paper's controller, eq. (11), as a policy on the local observation.

Agent i plans, over the coming interval of length T, to reach the average over itself and
its in-neighbours of their *coasted* states (paper Remark 1; docs: environment.md, "Exact dynamics"):

    a_v = mean_{j in {i} u N_i} (v_j - v_i)
    a_x = mean_{j in {i} u N_i} ((x_j - x_i) + T (v_j - v_i))

and the minimum-energy affine input realising that plan is exactly eq. (11):
``u(t_k+) = -6 e_x / T^2 - 4 e_v / T`` and ``u(t_{k+1}-) = 6 e_x / T^2 + 2 e_v / T``.

The policy reads nothing but the observation (its rows, mask and clock) and the
environment's settings (``T_s``, modes, layout): no state, no global information.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fxc_env.config import config_of
from fxc_env.core.arrays import is_numpy, namespace
from fxc_env.core.dynamics import input_from_plan
from fxc_env.policies.protocol import Policy


class ReferencePolicy(Policy):
    """Eq. (11) for every action mode (``plan``, ``plan_balanced``, ``accel``; ``residual``: zeros, the environment adds eq. 11) and observation mode.

    ``ReferencePolicy(env)(observations)`` maps the parallel env's ``{agent: observation}`` to
    ``{agent: action}`` (:mod:`fxc_env.policies.protocol`), one agent's observation ``(obs_size,)``
    (or a dict observation) to its action ``(2 dim,)`` (``(n dim,)`` for a general linear agent: the
    plan ``e^{A T} e_i``, the generalised eq. (11)); an array with leading dimensions
    ``(..., obs_size)`` maps to ``(..., 2 dim)`` in one vectorised call. :meth:`act` takes
    numpy arrays or torch tensors (on any device) alike; :class:`fxc_env.policies.torchrl_reference.ReferenceModule`
    wraps it as a TorchRL module.
    """

    def __init__(self, env: Any) -> None:
        self.config = config_of(env, "ReferencePolicy")
        self.layout = self.config.layout
        # One matrix product sums the x rows, the v rows and the mask of every agent in a
        # single pass over the observations: columns [sum (x_j - x_i) | sum (v_j - v_i) | d_i]
        # (a general agent's row has n components: [sum (z_j - z_i) per component | d_i]).
        layout = self.layout
        width = layout.row_size
        summation = np.zeros((layout.mask_end, width + 1))
        entry = np.arange(width)
        for slot in range(layout.slots):
            summation[slot * width + entry, entry] = 1.0
        summation[layout.rows_end : layout.mask_end, width] = 1.0
        #: General agents: per instant, the free motion in the observation's units, ``(K + 1, n, n)``
        #: (``F_k`` in raw mode; ``R F_k R^{-1}`` with ``R = diag(row_scales)`` when normalized).
        self._motion = None
        config = self.config
        if config.model is not None:
            motion = config.interval_maps.motion[np.minimum(np.arange(config.n_intervals + 1), config.n_intervals - 1)]
            if config.obs_mode == "normalized":
                scales = config.row_scales
                motion = scales[:, :, None] * motion / scales[:, None, :]
            self._motion = motion
        self._summation = summation

    def step(self, engine: Any) -> Any:
        """Play one interval of ``engine`` (a :class:`~fxc_env.engine.ConsensusEngine` of this config) under eq. (11); its :class:`StepOutcome`.

        Where its agents observe exactly (:func:`~fxc_env.engine.reference.exact_observations`) and
        the install built the compiled kernel (:data:`~fxc_env.engine.reference.KERNEL`):
        :meth:`ConsensusEngine.step_reference <fxc_env.engine.ConsensusEngine.step_reference>`, the
        plan from the neighbour sums alone, no observations; else
        ``engine.step(self.act(engine.observations()))`` (numpy or torch). The same interval to rounding either way.
        """
        return engine.step_reference() if engine.neighbour_plans.exact else engine.step(self.act(engine.observations()))

    def act(self, obs: Any) -> Any:
        """Eq. (11) from flat observations ``(..., obs_size)``: actions ``(..., 2 dim)`` (numpy or torch)."""
        c, dim = self.config, self.config.dim
        xp = namespace(obs)
        sums = obs[..., : self.layout.mask_end] @ self._summation_for(xp, obs)  # padded rows are zero
        if self._motion is not None:
            return self._general_plan(sums, obs)
        weight = 1.0 / (sums[..., 2 * dim] + 1.0)  # 1 / (d_i + 1)
        normalized = c.obs_mode == "normalized"
        balanced = c.velocity_weight is not None
        # Rows are (x_j - x_i)/s and T (v_j - v_i)/s when normalized: the plan is scale-free.
        # plan_balanced: rows (x_j - x_i)/s and T_s (v_j - v_i)/s, the plan (a_x / s, T_s a_v / s) (raw: (a_x, T_s a_v)).
        clock_interval = obs[..., self.layout.mask_end + 1]  # T / T_s
        if normalized:
            drift = clock_interval if balanced else None  # what the v rows count for in a_x / s: T / T_s, or 1
        else:
            drift = clock_interval * c.settling_time  # T
        velocity_unit = c.settling_time if balanced and not normalized else None
        rel_x, rel_v = sums[..., :dim], sums[..., dim : 2 * dim]
        if is_numpy(xp):
            # numpy fast path: one component at a time, each operation over all agents (a
            # (..., dim) block broadcast against (..., 1) makes numpy loop over every agent's few entries).
            plan = np.empty((*sums.shape[:-1], 2 * dim), dtype=sums.dtype)
            for component in range(dim):
                x_part, v_part = rel_x[..., component], rel_v[..., component]
                plan[..., component] = weight * (x_part + (v_part if drift is None else drift * v_part))
                plan[..., dim + component] = (
                    weight * v_part if velocity_unit is None else weight * v_part * velocity_unit
                )
        else:
            column = weight[..., None]
            moved = rel_v if drift is None else drift[..., None] * rel_v
            velocity = column * rel_v if velocity_unit is None else column * rel_v * velocity_unit
            plan = xp.concat([column * (rel_x + moved), velocity], axis=-1)
        if c.action_mode in ("plan", "plan_balanced"):
            return plan
        if c.action_mode == "residual":  # the environment adds this very plan: no correction
            return xp.zeros_like(plan)
        # accel, normalized: u = (s / T^2) * alpha, with input_from_plan at T = 1 in these units.
        interval = 1.0 if normalized else drift[..., None]
        return xp.concat(input_from_plan(plan[..., :dim], plan[..., dim:], interval), axis=-1)

    def _general_plan(self, sums: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """A general agent's plan ``Delta_i = e^{A T} e_i`` with ``e_i`` the mean relative state (docs: agent-models.md, "Agent models and formations").

        ``e_i = (1 / (d_i + 1)) sum_j (z_j - z_i)`` per component, read off the rows; the
        interval ``k`` comes from the clock (``k / K``), so the free motion is exact per agent.
        """
        c, layout = self.config, self.layout
        n, dim = c.n_states, c.dim
        width = layout.row_size
        mean = sums[..., :width] / (sums[..., width : width + 1] + 1.0)
        k = np.rint(obs[..., layout.mask_end + 2] * c.n_intervals).astype(np.int64)
        motion = self._motion[np.clip(k, 0, c.n_intervals)]  # (..., n, n)
        plan = motion @ mean.reshape((*mean.shape[:-1], n, dim))
        return plan.reshape(mean.shape)

    def _summation_for(self, xp: Any, obs: Any) -> Any:
        """The summation matrix in ``obs``'s namespace, dtype and device (cached per device and dtype)."""
        if is_numpy(xp):
            return self._summation
        key = (str(obs.device), str(obs.dtype))
        cached = self.__dict__.setdefault("_device_summation", {})
        if key not in cached:
            cached[key] = xp.asarray(self._summation, dtype=obs.dtype, device=obs.device)
        return cached[key]
