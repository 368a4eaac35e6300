"""The per-interval maps of a :class:`~fxc_env.core.linear.LinearModel`: steering plans in closed form.

The model, its scaled frame and its notation are :mod:`fxc_env.core.linear`'s. A plan is solved in
that frame by two ``(M, n) @ (n, n)`` products per step; ``G(T)`` and its inverse never appear.
:attr:`IntervalMaps.scaled_condition` reports ``cond(W_b)`` per interval (about 14 for the double
integrator, 7.4e3 for a chain of order 4, whatever T), and the achieved change equals Delta up to
``~ cond(W_b) eps`` in the scaled frame (docs: agent-models.md, "Solving in the scaled frame").
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg

from fxc_env.core import validation
from fxc_env.core.arrays import namespace
from fxc_env.core.validation import ArgumentError

#: Points of normalised time ``sigma`` on which the peak input of a non-polynomial model is evaluated.
PEAK_GRID_POINTS = 65
#: Rows per chunk when a peak is evaluated on the grid (bounds the temporary memory).
_PEAK_CHUNK = 4096


class IntervalMaps:
    """The per-interval maps of a :class:`LinearModel` for a fixed schedule of K interval lengths.

    Built by :meth:`LinearModel.interval_maps`. The operations take an interval index k
    (``0 <= k < K``) and per-axis states ``(..., n)`` whose leading dimensions broadcast.

    Attributes (all read-only arrays):
        model: the :class:`LinearModel`.
        intervals: ``(K,)`` interval lengths T_k in seconds.
        motion: ``(K, n, n)`` free motion ``F_k = e^{A T_k}``.
        scale: ``(K, n)`` the state scaling ``D = h^{levels}`` (units of the state / scaled state).
        balance: ``(K, n)`` the diagonal balancing ``S = diag(W)^{-1/2}`` of the unit-time Gramian.
        cholesky: ``(K, n, n)`` lower ``L`` with ``S W S = L L^T``.
        a_hat: ``(K, n, n)`` ``Ahat = T D^{-1} A D``, the scaled state matrix.
        scaled_condition: ``(K,)`` the 2-norm condition number of ``S W S``.
        input_polynomials: ``(K, n, m, n)`` when ``model.polynomial_input``: row j maps the scaled
            costate ``nu`` to the coefficient of ``tau^j`` of ``T u``, ``tau = 1 - s / T``; else None.
    """

    def __init__(self, model: Any, intervals: Any) -> None:  # a core.linear.LinearModel (no import: it imports this)
        lengths = np.array(validation.interval_lengths("intervals", intervals))
        self.model = model
        n = model.n_states
        h, a_hat = model._frame(lengths)
        with np.errstate(all="ignore"):  # an overflow is caught below, naming the interval
            motion_hat, unit = model._van_loan(a_hat, np.ones_like(lengths))
        diagonal = np.diagonal(unit, axis1=-2, axis2=-1)
        bad = ~np.all(np.isfinite(unit), axis=(-2, -1)) | np.any(~(diagonal > 0), axis=-1)
        balance = np.where(bad[:, None], 1.0, 1.0 / np.sqrt(np.where(bad[:, None], 1.0, diagonal)))
        balanced = balance[:, :, None] * unit * balance[:, None, :]
        try:
            if np.any(bad):
                raise np.linalg.LinAlgError
            cholesky = np.linalg.cholesky(balanced)
        except np.linalg.LinAlgError:
            k = next(k for k in range(len(lengths)) if bad[k] or not _positive_definite(balanced[k]))
            raise ArgumentError(
                f"intervals: the controllability Gramian is numerically singular or not finite over the interval "
                f"T = {float(lengths[k])!r} s (index {k}): (A, B) is nearly uncontrollable there, or e^(A T) "
                "leaves float64's range"
            ) from None
        eigenvalues = np.linalg.eigvalsh(balanced)
        self.intervals = lengths
        self.motion = model._ratio(h) * motion_hat
        self.scale = h[:, None] ** model.levels[None, :]
        self.balance = balance
        self.cholesky = cholesky
        self.a_hat = a_hat
        self.scaled_condition = eigenvalues[:, -1] / eigenvalues[:, 0]
        self.input_polynomials = None
        if model.polynomial_input:
            # T u(T sigma) = B^T e^{Ahat^T tau} nu = sum_j tau^j B^T (Ahat^T)^j nu / j!.
            rows = [np.broadcast_to(model.B.T, (len(lengths), *model.B.T.shape))]
            for j in range(1, n):
                rows.append(rows[-1] @ np.swapaxes(a_hat, -1, -2) / j)
            self.input_polynomials = np.stack(rows, axis=1)
            nonzero = np.flatnonzero(np.any(self.input_polynomials != 0, axis=(0, 2, 3)))
            self._degree = int(nonzero[-1]) if nonzero.size else 0
            # (K, n, (degree + 1) m): nu @ this gives the coefficients of T u, coefficient-major.
            used = self.input_polynomials[:, : self._degree + 1]
            self._coefficients_t = np.ascontiguousarray(np.swapaxes(used.reshape(len(lengths), -1, n), -1, -2))
        for array in (self.intervals, self.motion, self.scale, self.balance, self.cholesky, self.a_hat):
            array.setflags(write=False)
        self.scaled_condition.setflags(write=False)
        if self.input_polynomials is not None:
            self.input_polynomials.setflags(write=False)
        # Contiguous transposes for the (M, n) @ (n, n) products of the stepping path.
        self._motion_t = np.ascontiguousarray(np.swapaxes(self.motion, -1, -2))
        # The Cholesky factor's inverse, by triangular solves in the scaled frame (well conditioned),
        # with the scalings folded in: y = delta @ _forward = L^{-1} S D^{-1} delta, nu = y @ _backward.
        inverse = _lower_inverse(cholesky)
        self._forward = np.ascontiguousarray(np.swapaxes(inverse, -1, -2) * (balance / self.scale)[:, :, None])
        self._backward = np.ascontiguousarray(inverse * balance[:, None, :])
        self._grid: dict[int, np.ndarray] = {}

    @property
    def n_intervals(self) -> int:
        """K."""
        return len(self.intervals)

    def __repr__(self) -> str:
        return f"IntervalMaps(n_intervals={self.n_intervals}, model={self.model!r})"

    # ---------------------------------------------------------------- checks
    def _index(self, k: Any) -> int:
        return validation.integer("k", k, 0, self.n_intervals - 1)

    def _state(self, name: str, value: Any) -> np.ndarray:
        array = validation.real_array(name, value, f"an array (..., n) with n = {self.model.n_states}")
        if array.ndim < 1 or array.shape[-1] != self.model.n_states:
            raise ArgumentError(
                f"{name}: expected an array (..., n) with a last axis of n = {self.model.n_states}, got shape {array.shape}"
            )
        return array

    def _pair(self, Z: Any, delta: Any) -> tuple[np.ndarray, np.ndarray]:
        z, d = self._state("Z", Z), self._state("delta", delta)
        try:
            shape = np.broadcast_shapes(z.shape, d.shape)
        except ValueError:
            raise ArgumentError(f"delta: shape {d.shape} does not broadcast against Z's {z.shape}") from None
        return np.broadcast_to(z, shape), np.broadcast_to(d, shape)

    # ------------------------------------------------------------ operations
    def free_motion(self, k: Any, Z: Any) -> np.ndarray:
        """``F_k Z``: the state after interval k without input, ``(..., n)`` like ``Z``."""
        k = self._index(k)
        z = self._state("Z", Z)
        return apply_transposed(self._motion_t[k], z)

    def costate(self, k: Any, delta: Any) -> np.ndarray:
        """``lambda = G(T_k)^{-1} Delta`` in natural units, ``(..., n)``, solved in the scaled frame.

        The input is ``u(s) = B^T e^{A^T (T_k - s)} lambda``. For short intervals lambda is large
        (``~ T^{-(2 l + 1)}``); it is for checks, :meth:`steer` needs no natural-unit costate.
        """
        k = self._index(k)
        d = self._state("delta", delta)
        nu, _ = self._solve(k, d)
        return nu / (self.intervals[k] * self.scale[k])

    def steer(self, k: Any, Z: Any, delta: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Play interval k with the minimum-energy input that adds ``delta`` to the free motion.

        Args:
            k: interval index, ``0 <= k < K``.
            Z: ``(..., n)`` states at the start of the interval.
            delta: ``(..., n)`` planned changes relative to free motion (broadcasts against ``Z``).

        Returns:
            ``Z_next = F_k Z + delta`` ``(..., n)`` (the plan, exactly as planned); the energy
            ``int_0^T |u|^2 ds = Delta^T G^{-1} Delta`` (units of u^2 s) ``(...)``; and the peak
            ``max_s max_r |u_r(s)|`` ``(...)``. The peak is exact (end points and interior critical
            points) when ``model.polynomial_input``; otherwise it is the largest of
            :data:`PEAK_GRID_POINTS` equally spaced samples in ``[0, T]``, end points included
            (a value from below, within ``O((T / 64)^2 |u''|)`` of the true peak).
        """
        k = self._index(k)
        z, d = self._pair(Z, delta)
        nu, y = self._solve(k, d)
        T = self.intervals[k]
        energy = np.einsum("...i,...i->...", y, y) / T
        return apply_transposed(self._motion_t[k], z) + d, energy, self._peak(k, nu)

    def state_inside(self, k: Any, Z: Any, delta: Any, s: Any) -> tuple[np.ndarray, np.ndarray]:
        """State and input at offsets ``s`` (seconds, in ``[0, T_k]``, any shape ``P``) into interval k.

        Returns ``z(s)`` of shape ``P + (..., n)`` and ``u(s)`` of shape ``P + (..., m)``, where
        ``(..., n)`` is the broadcast shape of ``Z`` and ``delta``: one batched matrix exponential
        per point, so meant for dense plots and tests. ``z(T_k) = F_k Z + delta`` up to the solve's
        backward error (docs: agent-models.md, "Solving in the scaled frame").
        """
        k = self._index(k)
        z, d = self._pair(Z, delta)
        T = self.intervals[k]
        offsets = np.array(validation.real_array("s", s, "an offset or an array of offsets"))
        if not np.all(np.isfinite(offsets)) or np.any(offsets < 0) or np.any(offsets > T):
            raise ArgumentError(f"s: every offset must lie in [0, T_k] = [0, {T!r}] s")
        sigma = np.minimum(offsets.reshape(-1) / T, 1.0)
        n, m = self.model.n_states, self.model.n_inputs
        a_hat = np.broadcast_to(self.a_hat[k], (sigma.size, n, n))
        motion, partial = self.model._van_loan(a_hat, sigma)
        back = scipy.linalg.expm(np.swapaxes(a_hat, -1, -2) * (1.0 - sigma)[:, None, None])
        nu, _ = self._solve(k, d)
        flat_nu = nu.reshape(-1, n)
        w0 = (z / self.scale[k]).reshape(-1, n)
        carried = np.einsum("pij,pjk,mk->pmi", partial, back, flat_nu, optimize=True)
        state = self.scale[k] * (np.einsum("pij,mj->pmi", motion, w0) + carried)
        inputs = np.einsum("ri,pij,mj->pmr", self.model.B.T, back, flat_nu) / T
        return state.reshape(*offsets.shape, *z.shape), inputs.reshape(*offsets.shape, *z.shape[:-1], m)

    # --------------------------------------------------------------- helpers
    def _solve(self, k: int, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled costate ``nu = W^{-1} D^{-1} delta`` and ``y = L^{-1} S D^{-1} delta``, both ``(..., n)``.

        Rows times the interval's precomputed factors (docs: agent-models.md, "Solving in the scaled frame"): two
        ``(M, n) @ (n, n)`` products.
        """
        n = self.model.n_states
        shape = delta.shape
        y = delta.reshape(-1, n) @ self._forward[k]
        return (y @ self._backward[k]).reshape(shape), y.reshape(shape)

    def _peak(self, k: int, nu: np.ndarray) -> np.ndarray:
        """Peak ``|u|`` over interval k for scaled costates ``nu`` ``(..., n)``: ``(...)``."""
        n, m = self.model.n_states, self.model.n_inputs
        flat = nu.reshape(-1, n)
        T = self.intervals[k]
        if self.input_polynomials is not None:
            p = flat @ self._coefficients_t[k]  # (M, (degree + 1) m): T u as a polynomial in tau
            columns = [p[:, j * m : (j + 1) * m] for j in range(self._degree + 1)]
            peak = polynomial_peak(columns) / T  # (M, m)
        else:
            samples = self._grid_matrix(k)  # (n, G m)
            peak = np.empty((flat.shape[0], m))
            for start in range(0, flat.shape[0], _PEAK_CHUNK):
                values = np.abs(flat[start : start + _PEAK_CHUNK] @ samples)
                peak[start : start + _PEAK_CHUNK] = values.reshape(-1, PEAK_GRID_POINTS, m).max(axis=1) / T
        return (peak[:, 0] if m == 1 else peak.max(axis=-1)).reshape(nu.shape[:-1])

    def _grid_matrix(self, k: int) -> np.ndarray:
        """``(B^T e^{Ahat^T tau_j})^T`` side by side over ``tau_j = j / 64``: ``(n, G m)``, cached per k."""
        if k not in self._grid:
            tau = np.linspace(0.0, 1.0, PEAK_GRID_POINTS)
            back = scipy.linalg.expm(self.a_hat[k].T[None] * tau[:, None, None])
            rows = (self.model.B.T[None] @ back).reshape(-1, self.model.n_states)
            self._grid[k] = np.ascontiguousarray(rows.T)
        return self._grid[k]


def _positive_definite(matrix: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError:
        return False
    return True


def _lower_inverse(factor: np.ndarray) -> np.ndarray:
    """``L^{-1}`` of lower triangular ``L`` ``(K, n, n)`` by forward substitution against the identity, batched."""
    n = factor.shape[-1]
    inverse = np.zeros_like(factor)
    for i in range(n):
        row = np.zeros((*factor.shape[:-2], n))
        row[..., i] = 1.0
        row -= np.einsum("...j,...jc->...c", factor[..., i, :i], inverse[..., :i, :])
        inverse[..., i, :] = row / factor[..., i, i, None]
    return inverse


def apply_matrix(matrix: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``matrix @ z`` along the last axis of ``z`` ``(..., n)``, as one 2-D product."""
    return apply_transposed(np.ascontiguousarray(matrix.T), z)


def apply_transposed(matrix_t: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``z @ matrix_t`` for ``z`` ``(..., n)`` and a C-ordered ``(n, n)`` transpose, as one 2-D product."""
    return (z.reshape(-1, matrix_t.shape[0]) @ matrix_t).reshape(z.shape)


def polynomial_peak(p: list[Any]) -> Any:
    """``max_{tau in [0, 1]} |p(tau)|`` for ascending coefficients ``p = [p0, ..., pd]``, d <= 3, each ``(...)``.

    The candidates are both ends and the real roots of ``p'(tau) = p1 + 2 p2 tau + 3 p3 tau^2``
    clipped to [0, 1], from the cancellation-free quadratic formula
    ``q = -(p2 + sign(p2) sqrt(p2^2 - 3 p1 p3))``, roots ``q / (3 p3)`` and ``p1 / q`` (the latter
    is the root ``-p1 / (2 p2)`` of a quadratic p). A degenerate case (no real root, a zero
    denominator) has no interior critical point: its candidate is taken at ``tau = 0``, an end
    already counted. numpy arrays or torch tensors; every division is by a nonzero number, so
    the peak's gradient is finite (the torch engine differentiates it).
    """
    if len(p) > 4:
        raise ValueError("polynomial_peak: degree above 3")
    p0 = p[0]
    xp = namespace(p0)
    peak = xp.abs(p0)
    if len(p) == 1:
        return peak
    total = p0 + p[1]
    for coefficient in p[2:]:
        total = total + coefficient
    peak = xp.maximum(peak, xp.abs(total))
    if len(p) == 2:
        return peak
    p1, p2 = p[1], p[2]
    p3 = p[3] if len(p) == 4 else None
    if p3 is None:
        roots = [_ratio(-p1, 2.0 * p2, xp)]
    else:
        discriminant = p2 * p2 - 3.0 * p1 * p3
        real = discriminant >= 0
        q = -(p2 + xp.copysign(xp.sqrt(xp.where(real, discriminant, xp.zeros_like(discriminant))), p2))
        roots = [_ratio(q, 3.0 * p3, xp, real), _ratio(p1, q, xp, real)]
    for root in roots:
        tau = xp.clip(root, 0.0, 1.0)
        inner = p2 if p3 is None else p2 + tau * p3
        peak = xp.maximum(peak, xp.abs(p0 + tau * (p1 + tau * inner)))
    return peak


def _ratio(numerator: Any, denominator: Any, xp: Any, valid: Any = None) -> Any:
    """``numerator / denominator`` where the denominator is nonzero (and ``valid``), else 0, never dividing by 0."""
    usable = denominator != 0
    if valid is not None:
        usable = usable & valid
    safe = xp.where(usable, denominator, xp.ones_like(denominator))
    return xp.where(usable, numerator / safe, xp.zeros_like(numerator))
