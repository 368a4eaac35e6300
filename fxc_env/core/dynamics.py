"""Exact double-integrator motion under an input that is affine in time.

Every agent obeys ``x' = v``, ``v' = u`` (paper eq. 10). On a sampling interval of length T
the input is the straight line ``u(t_k + s) = u0 + (u1 - u0) s / T``, ``0 <= s <= T``, given by
its values at both ends. The paper's controller (eq. 11) is of this form, and so are both
action modes. The state is then a polynomial in s (v quadratic, x cubic) and is evaluated in
closed form: no ODE solver and no time step.

All functions broadcast over leading dimensions: ``x, v, u0, u1`` are ``(..., dim)`` and
``T`` is a scalar or ``(..., 1)``. Units: seconds, metres, metres/second, metres/second^2.
They take numpy arrays or torch tensors alike (the array API, :mod:`fxc_env.core.arrays`);
:func:`advance_into` is numpy's in-place fast path of :func:`advance` with its costs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from fxc_env.core.arrays import namespace


def input_from_plan(plan_x: Any, plan_v: Any, T: Any, s: Any = None) -> tuple[Any, Any]:
    """Minimum-energy affine input that realises a planned change relative to coasting.

    The plan asks for ``x(t_k + T) = x + T v + a_x`` and ``v(t_k + T) = v + a_v``. The unique
    minimiser of ``integral |u|^2`` is ``u(t_k + s) = alpha + beta s`` with
    ``alpha = 6 a_x / T^2 - 2 a_v / T`` and ``beta = (6 a_v T - 12 a_x) / T^3`` (paper eq. 11,
    paper Remark 1). Returns the end values ``(u0, u1) = (alpha, alpha + beta T)``; ``s`` is unused
    (the signature of :func:`input_ends`' maps: this is the raw ``plan`` action's).
    """
    inv_t = 1.0 / T
    position_term = (6.0 * inv_t * inv_t) * plan_x
    velocity_term = (2.0 * inv_t) * plan_v
    return position_term - velocity_term, 2.0 * velocity_term - position_term


def advance(
    x: np.ndarray, v: np.ndarray, u0: np.ndarray, u1: np.ndarray, T: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """State at the end of the interval: ``x + T v + T^2 (2 u0 + u1) / 6`` and ``v + T (u0 + u1) / 2``."""
    dx, dv, _ = interval_increments(v, u0, u1, T)
    return x + dx, v + dv


def interval_increments(v: Any, u0: Any, u1: Any, T: Any) -> tuple[Any, Any, Any]:
    """The closed forms of one interval: ``(x(T) - x, v(T) - v, |u|^2 integral per component)``.

    ``T v + T^2 (2 u0 + u1) / 6``, ``T (u0 + u1) / 2`` and ``T (u0^2 + u0 u1 + u1^2) / 3``, with
    ``u0 + u1`` formed once. Plain arithmetic only, so the one map serves Python floats (the
    small-N path, :mod:`fxc_env.envs.small_n`), numpy arrays and torch tensors alike, and
    rounds alike on all of them.
    """
    total = u0 + u1
    return T * v + (T * T / 6.0) * (u0 + total), (0.5 * T) * total, (u0 * total + u1 * u1) * (T / 3.0)


def scaled_plan_ends(first: Any, second: Any, T: Any, s: Any) -> tuple[Any, Any]:
    """Input ends of a normalized ``plan`` action: the plan ``(s a_x, (s / T) a_v)`` at local scale ``s``."""
    return input_from_plan(s * first, (s / T) * second, T)


def accel_ends(first: Any, second: Any, T: Any, s: Any = None) -> tuple[Any, Any]:
    """Input ends of an ``accel`` action in raw units: the action itself (``s`` unused)."""
    return first, second


def scaled_accel_ends(first: Any, second: Any, T: Any, s: Any) -> tuple[Any, Any]:
    """Input ends of a normalized ``accel`` action: both halves times ``s / T^2``."""
    gain = s / (T * T)
    return gain * first, gain * second


def input_ends(
    plans: bool, normalized: bool, velocity_weight: float | None = None
) -> Callable[[Any, Any, Any, Any], tuple[Any, Any]]:
    """The map ``(first, second, T, s) -> (u(t_k+), u(t_{k+1}-))`` of an action mode, chosen once.

    ``plans``: the action is a plan (``plan``, ``plan_balanced`` and ``residual`` modes) rather
    than the input's ends; ``normalized``: it is in units of the local scale ``s``.
    ``velocity_weight`` ``W`` (s; ``T_s`` for ``plan_balanced``, None otherwise): the plan's
    velocity part is ``second / W`` (raw) or ``s second / W`` (normalized) instead of
    ``second`` or ``s second / T``. Scalar-safe like :func:`interval_increments`.
    """
    if plans and velocity_weight is not None:
        per_weight = 1.0 / velocity_weight
        if normalized:
            return lambda first, second, T, s: input_from_plan(s * first, (s * per_weight) * second, T)
        return lambda first, second, T, s: input_from_plan(first, per_weight * second, T)
    if plans:
        return scaled_plan_ends if normalized else input_from_plan
    return scaled_accel_ends if normalized else accel_ends


def state_inside(
    x: np.ndarray, v: np.ndarray, u0: np.ndarray, u1: np.ndarray, T: np.ndarray | float, s: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and input at offset ``s`` in ``[0, T]`` into the interval (dense plots).

    ``s`` broadcasts against ``x`` like ``T`` does (e.g. ``(P, 1, 1, 1)`` against ``(K, N, dim)``
    evaluates P points in each of K intervals). Returns ``x(s), v(s), u(s)`` of the broadcast shape.
    """
    slope = (u1 - u0) / T
    u = u0 + slope * s
    v_s = v + u0 * s + slope * s**2 / 2.0
    x_s = x + v * s + u0 * s**2 / 2.0 + slope * s**3 / 6.0
    return x_s, v_s, u


def advance_with_costs(x, v, u0, u1, T):
    """:func:`advance` with :func:`interval_energy` and :func:`interval_peak`: ``(x(T), v(T), energy, peak)``.

    The same closed forms with ``u0 + u1`` formed once: the engine's stepping path, on
    numpy arrays or torch tensors alike (:func:`advance_into` is numpy's in-place form, with
    the same arithmetic, so both backends round alike).
    """
    dx, dv, per_component = interval_increments(v, u0, u1, T)
    return x + dx, v + dv, *_costs(per_component, u0, u1, namespace(x, v, u0, u1))


def _costs(per_component: Any, u0: Any, u1: Any, xp: Any) -> tuple[Any, Any]:
    """The energy (summed over components) and the peak ``|u|`` (largest component, at an end), ``(...)``."""
    largest = xp.maximum(xp.abs(u0), xp.abs(u1))
    if per_component.shape[-1] == 1:
        return per_component[..., 0], largest[..., 0]
    return xp.sum(per_component, axis=-1), xp.max(largest, axis=-1)


def advance_into(
    x: np.ndarray, v: np.ndarray, u0: np.ndarray, u1: np.ndarray, T: float, x_out: np.ndarray, v_out: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`advance_with_costs` written into ``x_out`` and ``v_out``, returning the energy and the peak.

    numpy's fast path of the engine (no temporaries for the new state), where a handful of
    small arrays make numpy's per-call cost dominate. ``x_out`` may be ``x`` (and ``v_out``
    ``v``) to advance in place.
    """
    dx, dv, per_component = interval_increments(v, u0, u1, T)
    np.add(x, dx, out=x_out)
    np.add(v, dv, out=v_out)
    return _costs(per_component, u0, u1, np)


def interval_energy(u0: np.ndarray, u1: np.ndarray, T: np.ndarray | float) -> np.ndarray:
    """``integral_0^T |u|^2 ds = T (|u0|^2 + u0.u1 + |u1|^2) / 3``, summed over components: ``(...)``."""
    per_component = interval_increments(0.0, u0, u1, T)[2]
    xp = namespace(per_component)
    return per_component[..., 0] if per_component.shape[-1] == 1 else xp.sum(per_component, axis=-1)


def interval_peak(u0: np.ndarray, u1: np.ndarray) -> np.ndarray:
    """Peak ``|u|`` on the interval: the largest absolute component, reached at an end, ``(...)``."""
    return _costs(u0, u0, u1, namespace(u0, u1))[1]


def _clipped_pieces(u0, u1, T, u_max):
    """Split ``clip(u0 + (u1 - u0) s / T, -u_max, u_max)`` on ``[0, T]`` into 3 affine pieces.

    Returns the pieces' start ``p`` and length ``L`` (``(3, ...)``, zero-length pieces allowed),
    their value at the start ``f_p`` and slope ``c`` (0 where saturated).
    """
    xp = namespace(u0, u1)
    slope = (u1 - u0) / T
    flat = slope == 0
    safe = xp.where(flat, xp.ones_like(slope), slope)
    # Where the line crosses -u_max and +u_max, clipped to [0, T] (both 0 for a flat line).
    # Clipping by maximum/minimum: T may be a number or an array (one interval per episode).
    zero = xp.zeros_like(slope)
    cross_low = xp.where(flat, zero, xp.minimum(xp.maximum((-u_max - u0) / safe, zero), zero + T))
    cross_high = xp.where(flat, zero, xp.minimum(xp.maximum((u_max - u0) / safe, zero), zero + T))
    first, second = xp.minimum(cross_low, cross_high), xp.maximum(cross_low, cross_high)
    end = zero + T
    starts = xp.stack([zero, first, second])
    lengths = xp.stack([first, second - first, end - second])
    middle = u0 + slope * (starts + lengths / 2)
    saturated = xp.abs(middle) > u_max
    start_value = xp.where(saturated, xp.sign(middle) * u_max, u0 + slope * starts)
    piece_slope = xp.where(saturated, xp.zeros_like(starts), slope + xp.zeros_like(starts))
    return starts, lengths, start_value, piece_slope, saturated


def advance_clipped(x, v, u0, u1, T, u_max):
    """Exact motion under the affine input clipped per component to ``[-u_max, u_max]``.

    ``u_max`` is a number or an array that broadcasts against ``(..., dim)`` with a last
    axis of 1 (one limit per episode: ``(B, 1, 1)``); ``T`` a number or an array that
    broadcasts likewise.

    The clipped input is piecewise affine (at most three pieces, split where the line
    crosses ``±u_max``); each piece is integrated in closed form:
    ``v(T) = v + sum int u``, ``x(T) = x + T v + sum int (T - s) u(s) ds``.

    Returns:
        ``x(T), v(T)`` ``(..., dim)``; energy ``int |u|^2`` and peak ``|u|`` ``(...)``; and the
        saturated time per component ``(..., dim)`` in seconds.
    """
    xp = namespace(x, v, u0, u1)
    starts, lengths, f_p, c, saturated = _clipped_pieces(u0, u1, T, u_max)
    f_q = f_p + c * lengths
    velocity_gain = xp.sum(lengths * (f_p + f_q) / 2, axis=0)
    # int_0^L (T - p - tau)(f_p + c tau) dtau on each piece.
    remaining = T - starts
    position_gain = xp.sum(
        remaining * lengths * (f_p + c * lengths / 2) - lengths**2 * (f_p / 2 + c * lengths / 3), axis=0
    )
    energy_per_component = xp.sum(lengths * (f_p * f_p + f_p * f_q + f_q * f_q) / 3, axis=0)
    saturated_time = xp.sum(xp.where(saturated, lengths, xp.zeros_like(lengths)), axis=0)
    x_next = x + T * v + position_gain
    v_next = v + velocity_gain
    peak = interval_peak(u0, u1)
    limit = u_max[..., 0] if getattr(u_max, "ndim", 0) else u_max
    peak = xp.minimum(peak, xp.zeros_like(peak) + limit)
    return x_next, v_next, xp.sum(energy_per_component, axis=-1), peak, saturated_time
