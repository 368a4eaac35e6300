"""The agents' dynamics over one sampling interval, chosen once at construction (:func:`make_agents`).

- :class:`DoubleIntegratorAgents`: ``x' = v``, ``v' = u`` (paper eq. 10) under the affine input
  the action names, integrated by the closed forms of :mod:`fxc_env.core.dynamics`;
- :class:`LimitedDoubleIntegratorAgents`: the same input clipped to ``±u_max`` (one limit per
  episode), integrated piece by piece in closed form;
- :class:`LinearAgents`: a general ``z' = A z + B u`` per axis (docs: agent-models.md, "Agent models and formations"): the
  action is a plan ``Delta`` and the input the minimum-energy one (:mod:`fxc_env.core.linear`).

Every part maps ``(state, actions)`` at ``t_k`` to an :class:`Interval` without touching the
engine's state (on numpy the new state goes into the spare buffer ``out``, adopted once finite).
States are ``(B, N, n, dim)``, component major, space axis last.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core import dynamics, interval_maps, linear, slots
from fxc_env.core.metrics import disagreement, spread_any
from fxc_env.core.validation import ArgumentError

#: Action entries (``B N 2 dim``) from which the numpy fast path of a step in blocks pays.
BLOCKED_FROM = 8192
#: Agents per block of that fast path (its temporaries, about 1 MiB, stay in the cache).
BLOCK_AGENTS = 16384


@dataclass(slots=True)
class Interval:
    """One interval's result, per episode ``(B,)`` or per agent ``(B, N)``.

    Attributes:
        state: the state at ``t_{k+1}``, ``(B, N, n, dim)`` (numpy: the spare buffer).
        energy: ``integral |u_i|^2 dt`` over the interval, ``(B, N)``.
        peak: peak ``|u_i|`` (largest component), ``(B, N)``.
        u_start, u_end: the commanded input at ``t_k+`` and ``t_{k+1}-``.
        saturated_fraction: share of the interval spent saturated, mean over components, ``(B, N)``.
        saturated_time: seconds saturated, mean over components, ``(B, N)``; None without a limit.
        plan: general agents' plans ``Delta`` per axis ``(B, N, dim, n)``; None otherwise.
        disagreement: ``D(t_{k+1})`` of :attr:`state`, ``(B,)``.
    """

    state: Any
    energy: Any
    peak: Any
    u_start: Any
    u_end: Any
    saturated_fraction: Any
    saturated_time: Any = None
    plan: Any = None
    disagreement: Any = None

    def outcome(self, reward: Any, terminated: Any) -> StepOutcome:
        """What the interval did, as a step returns it: ``reward`` ``(B,)`` and ``terminated`` beside its figures."""
        return StepOutcome(
            reward, self.energy, self.peak, self.u_start, self.u_end, self.saturated_fraction, terminated, self.plan
        )


@dataclass(slots=True)
class StepOutcome:
    """What one interval did, per episode ``(B,)`` or per agent ``(B, N)``.

    Attributes:
        reward: team reward ``log(D(t_k) + f) - log(D(t_{k+1}) + f)``, ``(B,)``.
        energy: ``integral |u_i|^2 dt`` over the interval, ``(B, N)``.
        peak_input: peak ``|u_i|`` (largest component) over the interval, ``(B, N)``.
        u_start, u_end: the commanded input at ``t_k+`` and ``t_{k+1}-``, ``(B, N, dim)``
            (the applied input is this line clipped to ``±u_max`` when that is set).
        saturated_fraction: share of the interval spent saturated, mean over components,
            ``(B, N)`` (zeros without ``u_max``).
        terminated: the deadline ``T_s`` was reached (``k = K``).
    """

    reward: np.ndarray
    energy: np.ndarray
    peak_input: np.ndarray
    u_start: np.ndarray
    u_end: np.ndarray
    saturated_fraction: np.ndarray
    terminated: bool
    #: General agents: the plans ``Delta`` applied, per axis ``(B, N, dim, n)`` (None for the double integrator).
    plan: np.ndarray | None = None


def state_disagreement(states: np.ndarray, config: EnvConfig) -> np.ndarray:
    """``D = sum_l T_s^l e_{z_l}`` of states ``(..., N, n, dim)`` in the engine's coordinates: ``(...)``.

    ``e_x + T_s e_v`` for the double integrator (and any model with n = 2); a chain of order 3
    adds ``T_s^2 e_a``; a single integrator has ``e_x`` alone. numpy arrays or torch tensors.
    """
    total = None
    for component in range(states.shape[-2]):
        term = (config.settling_time**component) * spread_any(states[..., component, :])
        total = term if total is None else total + term
    return total


class DoubleIntegratorAgents:
    """Double integrators under the affine input of the action (closed forms, paper eqs. 10-11).

    Args:
        config: the environment's settings (action and observation modes, ``T_s``, dim).
        backend: the engine's array backend.
    """

    def __init__(self, config: EnvConfig, backend: Any) -> None:
        self.config = config
        self.backend = backend
        self.dim = config.dim
        self.normalized = config.obs_mode == "normalized"
        # residual: the engine added the reference's plan
        self.plans = config.action_mode in ("plan", "plan_balanced", "residual")
        #: The action's input ends, chosen once (the small-N path plays the same map on floats).
        self._ends = dynamics.input_ends(self.plans, self.normalized, config.velocity_weight)
        #: Each episode's input limit ``u_max`` (m/s^2), ``(B,)``; None without a limit.
        self.u_max: Any = None
        self.no_saturation = backend.zeros((backend.n_episodes, config.n_agents))
        self.range_weights = np.array([1.0, config.settling_time])

    def inputs(self, actions: Any, T: Any, local_scale: Callable[[], Any], raw_plans: bool = False) -> tuple[Any, Any]:
        """The affine input's end values ``(u(t_k+), u(t_{k+1}-))`` of actions (the card's Action Space).

        ``T`` is the interval (a number, or ``(B, 1, 1)``); ``local_scale()`` gives ``s_i``
        ``(B, N)``, read in normalized mode only. ``raw_plans``: the actions are plans ``[a_x, a_v]``
        in metres and m/s whatever the action mode (:meth:`ConsensusEngine.step_reference
        <fxc_env.engine.ConsensusEngine.step_reference>`).
        """
        dim = self.dim
        if raw_plans:
            return dynamics.input_from_plan(actions[..., :dim], actions[..., dim:], T)
        s = local_scale()[..., None] if self.normalized else None
        return self._ends(actions[..., :dim], actions[..., dim:], T, s)

    def advance(
        self, state: Any, actions: Any, clock: Any, local_scale: Callable[[], Any], out: Any, raw_plans: bool = False
    ) -> Interval:
        """Play the coming interval of ``clock`` from ``state`` under ``actions`` (:meth:`inputs`); numpy writes into ``out``."""
        T = clock.interval(2)
        with np.errstate(over="ignore", invalid="ignore"):
            x, v = state[:, :, 0], state[:, :, 1]
            if out is not None and isinstance(T, float) and actions.size >= BLOCKED_FROM:
                # numpy fast path: block by block (in the cache), into the spare buffer (1.1-1.3x at N = 1e6).
                u0, u1, energy, peak = self._advance_blocked(state, actions, T, local_scale, out, raw_plans)
                following = out
            elif out is not None:
                # numpy fast path: the closed forms written into the spare buffer (no temporaries).
                u0, u1 = self.inputs(actions, T, local_scale, raw_plans)
                energy, peak = dynamics.advance_into(x, v, u0, u1, T, out[:, :, 0], out[:, :, 1])
                following = out
            else:
                u0, u1 = self.inputs(actions, T, local_scale, raw_plans)
                x_next, v_next, energy, peak = dynamics.advance_with_costs(x, v, u0, u1, T)
                following = self.backend.xp.stack([x_next, v_next], axis=2)
            return Interval(
                following, energy, peak, u0, u1, self.no_saturation, None, None, self.disagreement(following)
            )

    def _advance_blocked(
        self, state: Any, actions: Any, T: float, local_scale: Callable[[], Any], out: Any, raw_plans: bool
    ) -> tuple[Any, ...]:
        """numpy fast path of :meth:`advance` in lock step: :meth:`inputs` and the closed forms per block of agents.

        Every operation is element-wise, so the episodes' agents are taken as one run of
        ``B N`` and cut in blocks of :data:`BLOCK_AGENTS`, each played with the very lines of
        the generic path (the same values) while its temporaries stay in the cache.
        Returns ``u0, u1`` ``(B, N, dim)`` and the energy and peak ``(B, N)``.
        """
        b, n, dim = actions.shape[0], actions.shape[1], self.dim
        rows = b * n
        flat_actions = actions.reshape(rows, 1, -1)
        flat_state = state.reshape(rows, 2, dim)
        flat_out = out.reshape(rows, 2, dim)
        flat_scale = local_scale().reshape(rows, 1) if self.normalized and not raw_plans else None
        u0, u1 = np.empty((rows, 1, dim)), np.empty((rows, 1, dim))
        energy, peak = np.empty((rows, 1)), np.empty((rows, 1))
        for start in range(0, rows, BLOCK_AGENTS):
            part = slice(start, start + BLOCK_AGENTS)
            block_scale = None if flat_scale is None else flat_scale[part]
            u0[part], u1[part] = self.inputs(flat_actions[part], T, lambda: block_scale, raw_plans)  # noqa: B023
            x, v = flat_state[part, None, 0], flat_state[part, None, 1]
            energy[part], peak[part] = dynamics.advance_into(
                x, v, u0[part], u1[part], T, flat_out[part, None, 0], flat_out[part, None, 1]
            )
        return u0.reshape(b, n, dim), u1.reshape(b, n, dim), energy.reshape(b, n), peak.reshape(b, n)

    def disagreement(self, state: Any) -> Any:
        """``D = e_x + T_s e_v`` per episode ``(B,)``; for ``dim = 1`` from one max and one min over agents."""
        xp = self.backend.xp
        if self.dim == 1:
            values = state[..., 0]  # (B, N, 2)
            if self.backend.is_numpy:
                if values.size > slots.SMALL:
                    # numpy fast path: reducing over a middle axis is slow in numpy (10x at
                    # N = 1e6); agents last is not.
                    values = np.ascontiguousarray(np.swapaxes(values, 1, 2))  # (B, 2, N)
                    ranges = values.max(axis=-1) - values.min(axis=-1)
                else:
                    ranges = values.max(axis=1) - values.min(axis=1)
                return ranges @ self.range_weights  # e_x + T_s e_v
            ranges = xp.max(values, axis=1) - xp.min(values, axis=1)
            return ranges[:, 0] + self.config.settling_time * ranges[:, 1]
        return disagreement(state[:, :, 0], state[:, :, 1], self.config.settling_time)


class LimitedDoubleIntegratorAgents(DoubleIntegratorAgents):
    """Double integrators whose input is clipped to ``±u_max`` per component (one limit per episode)."""

    def advance(
        self, state: Any, actions: Any, clock: Any, local_scale: Callable[[], Any], out: Any, raw_plans: bool = False
    ) -> Interval:
        T = clock.interval(2)
        with np.errstate(over="ignore", invalid="ignore"):
            u0, u1 = self.inputs(actions, T, local_scale, raw_plans)
            x_next, v_next, energy, peak, saturated_time = dynamics.advance_clipped(
                state[:, :, 0], state[:, :, 1], u0, u1, T, self.u_max[:, None, None]
            )
            if out is not None:
                out[:, :, 0] = x_next
                out[:, :, 1] = v_next
                following = out
            else:
                following = self.backend.xp.stack([x_next, v_next], axis=2)
            per_agent = self.backend.xp.mean(saturated_time, axis=-1)
            fraction = per_agent / (T[..., 0] if clock.per_episode else T)
            return Interval(following, energy, peak, u0, u1, fraction, per_agent, None, self.disagreement(following))


class LinearAgents:
    """General linear agents ``z' = A z + B u`` per axis, steered by plans (docs: agent-models.md, "Agent models and formations").

    Args:
        config: the environment's settings (its model and interval maps).
        backend: the engine's array backend (numpy, or torch: :meth:`_advance_device`).
    """

    def __init__(self, config: EnvConfig, backend: Any) -> None:
        self.config = config
        self.backend = backend
        self.normalized = config.obs_mode == "normalized"
        self.u_max: Any = None
        self.no_saturation = backend.zeros((backend.n_episodes, config.n_agents))
        self._row_scales = backend.array(config.row_scales)
        #: torch: the interval maps' factors on the device (:class:`_DeviceMaps`); None on numpy.
        self._device_maps = None if backend.is_numpy else _DeviceMaps(config.interval_maps, backend)

    def inputs(self, actions: Any, T: Any, local_scale: Callable[[], Any]) -> tuple[Any, Any]:
        """General agents' actions are plans, not input end values: the input is found by :meth:`advance`."""
        raise ArgumentError(
            f"actions: {self.config.agent_model!r} agents take plans (the minimum-energy input follows from them); "
            "the input's end values are StepOutcome.u_start and u_end"
        )

    def advance(
        self, state: Any, actions: Any, clock: Any, local_scale: Callable[[], Any], out: Any, raw_plans: bool = False
    ) -> Interval:
        """The plan's minimum-energy input over interval k (:mod:`fxc_env.core.linear`); ``raw_plans`` is refused.

        ``actions`` ``(B, N, n dim)`` are plans ``Delta`` (terminal change relative to free
        motion, component-major like the state), in normalized mode ``alpha`` with
        ``Delta_l = s_i alpha_l / row_scales_l``. The input at both ends is ``(B, N, dim)``
        (``(B, N, dim, m)`` for m > 1 inputs).
        """
        if raw_plans:
            raise ArgumentError(
                f"raw_plans: expected False for {self.config.agent_model!r} agents (plans [a_x, a_v] are the double integrator's), got True"
            )
        c, k = self.config, clock.k
        b, n_agents, n, dim = actions.shape[0], c.n_agents, c.n_states, c.dim
        with np.errstate(over="ignore", invalid="ignore"):
            plan = actions.reshape(b, n_agents, n, dim)
            if self.normalized:
                plan = plan * (local_scale()[:, :, None, None] / self._row_scales[k][:, None])
            if self._device_maps is not None:
                return self._advance_device(state, plan, k)
            maps = c.interval_maps
            per_axis = np.swapaxes(state, -1, -2)  # (B, N, dim, n), the axis order of core.linear
            delta = np.swapaxes(plan, -1, -2)
            following, energy, peak = maps.steer(k, per_axis, delta)
            # The input at both ends: u(0+) = B^T F^T lambda, u(T-) = B^T lambda.
            costate = maps.costate(k, delta)  # (B, N, dim, n)
            model = c.model
            u_end = costate @ model.B
            u_start = costate @ (maps.motion[k] @ model.B)
            if model.n_inputs == 1:
                u_start, u_end = u_start[..., 0], u_end[..., 0]
            out[...] = np.swapaxes(following, -1, -2)
            energy, peak, disagreement = energy.sum(axis=-1), peak.max(axis=-1), state_disagreement(out, c)
            return Interval(out, energy, peak, u_start, u_end, self.no_saturation, None, delta, disagreement)

    def _advance_device(self, state: Any, plan: Any, k: int) -> Interval:
        """:meth:`advance` on torch: the same maps (:meth:`IntervalMaps.steer <fxc_env.core.linear.IntervalMaps.steer>`,
        ``costate``) as products with the device's copies of their factors, differentiable throughout."""
        xp, maps, model = self.backend.xp, self._device_maps, self.config.model
        per_axis = xp.matrix_transpose(state)  # (B, N, dim, n), the axis order of core.linear
        delta = xp.matrix_transpose(plan)
        y = delta @ maps.forward[k]
        nu = y @ maps.backward[k]
        following = xp.matrix_transpose(per_axis @ maps.motion_t[k] + delta)
        T = maps.host_intervals[k]
        energy = xp.sum(y * y, axis=-1) / T
        costate = nu / (T * maps.scale[k])
        u_end = costate @ maps.B
        u_start = costate @ maps.motion_B[k]
        if model.n_inputs == 1:
            u_start, u_end = u_start[..., 0], u_end[..., 0]
        energy, peak = xp.sum(energy, axis=-1), xp.max(maps.peak(k, nu), axis=-1)
        disagreement = state_disagreement(following, self.config)
        return Interval(following, energy, peak, u_start, u_end, self.no_saturation, None, delta, disagreement)

    def disagreement(self, state: Any) -> Any:
        """``D = sum_l T_s^l e_{z_l}`` per episode ``(B,)`` (:func:`state_disagreement`)."""
        return state_disagreement(state, self.config)


class _DeviceMaps:
    """The factors of :class:`~fxc_env.core.linear.IntervalMaps` that a step multiplies by, as device tensors.

    The maps are built once on the host (numpy: matrix exponentials, Gramians, Cholesky
    factors); the torch step is then products with these copies only, so the state, energy,
    input and peak are differentiable in the plan (the peak by the same candidates as
    :func:`fxc_env.core.interval_maps.polynomial_peak`, or the same grid of samples).
    """

    def __init__(self, maps: Any, backend: Any) -> None:
        self.maps = maps
        self.backend = backend
        self.host_intervals = [float(t) for t in maps.intervals]
        self.forward = backend.array(maps._forward)
        self.backward = backend.array(maps._backward)
        self.motion_t = backend.array(maps._motion_t)
        self.scale = backend.array(maps.scale)
        self.B = backend.array(maps.model.B)
        self.motion_B = backend.array(maps.motion @ maps.model.B)
        self.coefficients_t = None if maps.input_polynomials is None else backend.array(maps._coefficients_t)
        self._grid: dict[int, Any] = {}

    def peak(self, k: int, nu: Any) -> Any:
        """Peak ``|u|`` over interval k for scaled costates ``nu`` ``(..., n)``: ``(...)`` (``IntervalMaps._peak``)."""
        xp, m, T = self.backend.xp, self.maps.model.n_inputs, self.host_intervals[k]
        if self.coefficients_t is not None:
            p = nu @ self.coefficients_t[k]  # (..., (degree + 1) m): T u as a polynomial in tau
            columns = [p[..., j * m : (j + 1) * m] for j in range(self.maps._degree + 1)]
            peak = interval_maps.polynomial_peak(columns) / T
        else:
            if k not in self._grid:
                self._grid[k] = self.backend.array(self.maps._grid_matrix(k))
            values = xp.abs(nu @ self._grid[k])
            peak = xp.max(xp.reshape(values, (*values.shape[:-1], linear.PEAK_GRID_POINTS, m)), axis=-2) / T
        return peak[..., 0] if m == 1 else xp.max(peak, axis=-1)


class Formation:
    """Formation offsets ``h`` ``(N, n, dim)`` (docs: agent-models.md, "Agent models and formations"): the engine plays ``zeta = z - e^{A t} h``.

    The offsets' trajectory ``e^{A t} h`` is a free motion (no input), so ``zeta`` obeys the
    same dynamics under the same inputs, and consensus of ``zeta`` is the formation. Without
    offsets both maps are the identity.
    """

    def __init__(self, config: EnvConfig, backend: Any) -> None:
        self.backend = backend
        self.n_states = config.n_states
        self.n_intervals = config.n_intervals
        self.offsets = None if config.formation is None else backend.array(config.formation)
        #: ``e^{A t_k}`` per instant ``(K + 1, n, n)`` (``config.formation_motion``), or None.
        self.motion = None if config.formation is None else backend.array(config.formation_motion)

    def initial_state(self, x0: Any, v0: Any) -> Any:
        """The engine's state ``(B, N, n, dim)`` for initial positions and velocities ``(B, N, dim)``.

        Higher state components (a chain's acceleration, ...) start at 0; a single integrator
        has no velocity (``v0`` is not used). With offsets, ``h`` is subtracted (t = 0).
        """
        xp, n = self.backend.xp, self.n_states
        fresh = xp.stack([x0, v0][:n] + [xp.zeros_like(x0)] * (n - 2), axis=2)
        return fresh if self.offsets is None else fresh - self.offsets

    def absolute(self, state: Any, clock: Any) -> Any:
        """The agents' states ``z = zeta + e^{A t_k} h`` ``(B, N, n, dim)`` at the clock's instant."""
        if self.offsets is None:
            return state
        xp, n = self.backend.xp, self.n_states
        motion = clock.per_instant(xp.reshape(self.motion, (self.n_intervals + 1, -1)))
        motion = xp.reshape(motion, (*motion.shape[:-1], n, n))  # (n, n) or (B, 1, n, n)
        return state + motion @ self.offsets


def make_agents(config: EnvConfig, backend: Any) -> DoubleIntegratorAgents | LinearAgents:
    """The agents' part for ``config``: general ``(A, B)``, clipped or plain double integrators.

    With a set of input limits every episode holds the set's first until a reset gives its own.
    """
    if config.model is not None:
        agents: DoubleIntegratorAgents | LinearAgents = LinearAgents(config, backend)
    elif config.u_max_choices is not None:
        agents = LimitedDoubleIntegratorAgents(config, backend)
    else:
        agents = DoubleIntegratorAgents(config, backend)
    if config.u_max_choices is not None:
        agents.u_max = backend.full(backend.n_episodes, config.u_max_choices[0])
    return agents
