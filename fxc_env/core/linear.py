"""General linear agents: exact free motion and minimum-energy steering over one interval.

Every agent obeys, on each of its ``dim`` space axes separately, the same linear model
``z' = A z + B u`` with state ``z`` in R^n and input ``u`` in R^m (per axis). The double
integrator of :mod:`fxc_env.core.dynamics` is ``A = [[0, 1], [0, 0]]``, ``B = [[0], [1]]``.
By convention ``z[0]`` is the position (metres) and the other components are the model's
further states (velocity, acceleration, ...); time is in seconds, ``A`` in 1/s.

On an interval of length T an agent plans ``Delta``, the change of its state relative to free
motion ``F(T) = e^{A T}``, realised by the minimum-energy input
``u(s) = B^T e^{A^T (T - s)} G(T)^{-1} Delta`` (controllability Gramian ``G``). Nothing here
forms or inverts the badly conditioned ``G(T)``: each interval is worked in normalised time and a
scaled state, ``w = D^{-1} z`` with ``D = h^levels``, ``h = min(T, 1 / rho(A))`` (docs:
agent-models.md, "The scaled frame", derives it).

Solving a plan over an interval in that frame: :mod:`fxc_env.core.interval_maps`.

Layout: a per-axis state is the last axis ``(..., n)`` of an array whose leading dimensions
(episodes, agents, space axes) broadcast; inputs come as ``(..., m)``. Matrices multiply the
last axis, so 1e5 agents x dim axes are a single ``(M, n) @ (n, n)`` product.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy.linalg

from fxc_env.core import validation
from fxc_env.core.interval_maps import PEAK_GRID_POINTS, IntervalMaps, apply_matrix  # noqa: F401 (re-exported)
from fxc_env.core.models import CHAIN_ORDERS, DEFAULT_DAMPING, DEFAULT_FREQUENCY, MODEL_NAMES, model_matrices  # noqa: F401
from fxc_env.core.validation import ArgumentError

#: The largest ``growth_rate * T_s`` an episode may span. The rounding of every step (1e-16 of the states) grows
#: with the free motion like ``e^{growth_rate t}``: the exact reference law ends near ``1e-13 e^{growth_rate T_s}``
#: (ring of 6, K = 200 uniform, A = [[0, 1], [0, g]] or [[g, 1], [0, 0]]: 3e-14 to 3e-13 x e^{g T_s}, so 6e-10 to
#: 6e-9 at 10, 1.5e-5 to 1.2e-4 at 20, 0.35 to 2.7 at 30, 53 to 400 at 35). Past 30 no law can promise agreement:
#: rounding alone is as large as the initial disagreement (and at 52 the states reach 5e22).
MAX_HORIZON_GROWTH = 30.0


# --------------------------------------------------------------------------- models
def is_double_integrator(A: Any, B: Any) -> bool:
    """Whether ``(A, B)`` is exactly the double integrator ``([[0, 1], [0, 0]], [[0], [1]])``.

    A length-2 ``B`` counts as the column. Never raises: anything else is ``False``. The
    engine uses this to keep the closed forms of :mod:`fxc_env.core.dynamics` bit for bit.
    """
    try:
        a = np.asarray(A, dtype=np.float64)
        b = np.asarray(B, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return False
    if b.shape == (2,):
        b = b[:, None]
    return (
        a.shape == (2, 2)
        and b.shape == (2, 1)
        and bool(np.array_equal(a, [[0.0, 1.0], [0.0, 0.0]]))
        and bool(np.array_equal(b, [[0.0], [1.0]]))
    )


def _real_matrix(name: str, value: Any, expected: str, copy: bool = True) -> np.ndarray:
    """``value`` as float64 (a copy unless ``copy`` is False), checked by :func:`fxc_env.core.validation.real_array`."""
    array = validation.real_array(name, value, expected)
    return np.array(array) if copy else array


def _structural_levels(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Breadth-first level of each state from the input through the nonzero pattern of A, ``(n,)`` int."""
    levels = np.full(A.shape[0], -1)
    frontier = np.any(B != 0, axis=1)
    levels[frontier] = 0
    level = 0
    while np.any(frontier):
        level += 1
        driven = np.any(A[:, frontier] != 0, axis=1) & (levels < 0)
        levels[driven] = level
        frontier = driven
    levels[levels < 0] = 0  # structurally unreachable (cannot happen for a controllable pair)
    return levels


class LinearModel:
    """A controllable per-axis model ``z' = A z + B u``, validated at construction.

    Args:
        A: ``(n, n)`` state matrix in 1/s, finite.
        B: ``(n, m)`` input matrix (a length-n vector is one input), finite.

    Raises:
        ArgumentError naming ``A`` or ``B`` (shape, type, non-finite entries) or ``A, B`` when
        the pair is not controllable (``rank [B, AB, ..., A^{n-1} B] < n``).

    Attributes:
        A: ``(n, n)`` read-only copy. B: ``(n, m)`` read-only copy.
        levels: ``(n,)`` structural levels of the states (docs: agent-models.md, "The scaled frame").
        time_scale: ``1 / rho`` in seconds with rho the spectral radius of A (``inf`` if rho = 0).
        growth_rate: the largest real part of A's eigenvalues in 1/s, or 0 for a model whose free
            motion does not grow exponentially (see :func:`check_horizon`).
        polynomial_input: True when A is nilpotent (exactly) and n <= 4: the minimum-energy input
            is then a polynomial of degree <= n - 1 in time and its peak is computed exactly.
    """

    def __init__(self, A: Any, B: Any) -> None:
        a = _real_matrix("A", A, "a square (n, n) array")
        if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] < 1:
            raise ArgumentError(f"A: expected a square (n, n) array with n >= 1, got shape {a.shape}")
        validation.finite_array("A", a)
        n = a.shape[0]
        b = _real_matrix("B", B, f"an (n, m) = ({n}, m) array")
        if b.shape == (n,):
            b = b[:, None]
        if b.ndim != 2 or b.shape[0] != n or b.shape[1] < 1:
            raise ArgumentError(
                f"B: expected an (n, m) = ({n}, m) array with m >= 1 (a length-{n} vector is one input), "
                f"got shape {b.shape}"
            )
        validation.finite_array("B", b)
        blocks = [b]
        for _ in range(n - 1):
            blocks.append(a @ blocks[-1])
        rank = int(np.linalg.matrix_rank(np.concatenate(blocks, axis=1)))
        if rank < n:
            raise ArgumentError(
                "A, B: expected a controllable pair; the controllability matrix [B, AB, ..., A^(n-1) B] "
                f"has rank {rank} < n = {n}"
            )
        a.setflags(write=False)
        b.setflags(write=False)
        self._A, self._B = a, b
        self.levels = _structural_levels(a, b)
        self.levels.setflags(write=False)
        rho = float(np.max(np.abs(np.linalg.eigvals(a))))
        self.time_scale = 1.0 / rho if rho > 0 and math.isfinite(1.0 / rho) else math.inf
        self.growth_rate = max(0.0, float(np.max(np.linalg.eigvals(a).real)))
        nilpotent = bool(np.all(np.linalg.matrix_power(a, n) == 0))
        self.polynomial_input = nilpotent and n <= 4
        self._gain = b @ b.T

    @classmethod
    def named(cls, name: Any, **parameters: Any) -> LinearModel:
        """The model of :func:`~fxc_env.core.models.model_matrices` (same arguments and errors)."""
        return cls(*model_matrices(name, **parameters))

    @property
    def A(self) -> np.ndarray:
        """``(n, n)`` state matrix (1/s), read-only."""
        return self._A

    @property
    def B(self) -> np.ndarray:
        """``(n, m)`` input matrix, read-only."""
        return self._B

    @property
    def n_states(self) -> int:
        """n, the state components per axis."""
        return self._A.shape[0]

    @property
    def n_inputs(self) -> int:
        """m, the input components per axis."""
        return self._B.shape[1]

    @property
    def is_double_integrator(self) -> bool:
        """Whether this is exactly the double integrator (:func:`is_double_integrator`)."""
        return is_double_integrator(self._A, self._B)

    def __repr__(self) -> str:
        return f"LinearModel(n_states={self.n_states}, n_inputs={self.n_inputs}, A={self._A.tolist()}, B={self._B.tolist()})"

    # ------------------------------------------------------------ scaled frame
    def _frame(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scale base h and ``Ahat`` for times ``t`` ``(K,)`` >= 0: ``(K,)`` and ``(K, n, n)``.

        ``Ahat_ij = t A_ij h^{l_j - l_i}``; with ``h = t`` the powers are combined into one
        integer power of t so that the unit couplings of a chain stay exactly 1.
        """
        h = np.where(t > 0, np.minimum(t, self.time_scale), 1.0)
        exponent = self.levels[None, :] - self.levels[:, None]  # l_j - l_i, (n, n)
        with np.errstate(all="ignore"):
            at_interval = t[:, None, None] ** (1 + exponent)
            capped = t[:, None, None] * h[:, None, None] ** exponent
            factor = np.where((h == t)[:, None, None], at_interval, capped)
            a_hat = np.where(self._A != 0, factor * self._A, 0.0)
        return h, a_hat

    def _van_loan(self, a_hat: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``e^{Ahat sigma}`` and ``V(sigma) = int_0^sigma e^{Ahat r} B B^T e^{Ahat^T r} dr``, both ``(K, n, n)``.

        Van Loan's block exponential holds ``e^{-Ahat^T sigma}`` beside the Gramian, which for a
        strongly stable model over a long interval (a heavy damping over the paper's first 12 s) is
        astronomically large, and reading ``V`` back multiplies it by the tiny ``e^{Ahat^T sigma}``:
        all digits lost. So the block is exponentiated only over ``sigma / 2^m`` with
        ``|Ahat sigma| / 2^m <= 1`` and the result doubled m times,
        ``V(2 s) = V(s) + e^{Ahat s} V(s) e^{Ahat^T s}``, ``e^{Ahat 2 s} = (e^{Ahat s})^2``:
        every term is a positive semi-definite sum, so no cancellation, for any stable or unstable A.
        """
        n = self.n_states
        scaled = a_hat * sigma[..., None, None]
        norms = np.max(np.sum(np.abs(scaled), axis=-1), axis=-1) if scaled.size else np.zeros(0)
        largest = float(np.max(norms, initial=0.0, where=np.isfinite(norms)))
        doublings = min(60, math.ceil(math.log2(largest))) if largest > 1.0 else 0
        block = np.zeros((*a_hat.shape[:-2], 2 * n, 2 * n))
        block[..., :n, :n] = scaled
        block[..., :n, n:] = self._gain * sigma[..., None, None]
        block[..., n:, n:] = -np.swapaxes(scaled, -1, -2)
        exp = scipy.linalg.expm(block / 2.0**doublings)
        motion = exp[..., :n, :n]
        gramian = exp[..., :n, n:] @ np.swapaxes(motion, -1, -2)
        for _ in range(doublings):
            gramian = gramian + motion @ gramian @ np.swapaxes(motion, -1, -2)
            motion = motion @ motion
        return motion, 0.5 * (gramian + np.swapaxes(gramian, -1, -2))

    def free_motion_matrix(self, t: Any) -> np.ndarray:
        """``e^{A t}`` for a time t >= 0 in seconds (scalar or array ``(...)``): ``(..., n, n)``."""
        times = _times("t", t)
        flat = times.reshape(-1)
        h, a_hat = self._frame(flat)
        motion = scipy.linalg.expm(a_hat) if flat.size else np.zeros((0, self.n_states, self.n_states))
        return (self._ratio(h) * motion).reshape(*times.shape, self.n_states, self.n_states)

    def gramian(self, t: Any) -> np.ndarray:
        """The controllability Gramian ``G(t)`` in natural units, ``(..., n, n)`` (diagnostics and tests).

        Computed as ``t D W D`` in the scaled frame; its entries are accurate, but for short t it is
        badly conditioned: solve plans with :meth:`interval_maps`, not with this matrix.
        """
        times = _times("t", t)
        flat = times.reshape(-1)
        h, a_hat = self._frame(flat)
        n = self.n_states
        if not flat.size:
            return np.zeros((*times.shape, n, n))
        _, unit = self._van_loan(a_hat, np.ones_like(flat))
        d = h[:, None] ** self.levels[None, :]
        out = flat[:, None, None] * d[:, :, None] * unit * d[:, None, :]
        return out.reshape(*times.shape, n, n)

    def _ratio(self, h: np.ndarray) -> np.ndarray:
        """``D_i / D_j = h^{l_i - l_j}``, ``(K, n, n)``."""
        return h[:, None, None] ** (self.levels[:, None] - self.levels[None, :])

    def interval_maps(self, intervals: Any) -> IntervalMaps:
        """Precompute everything per interval length for a schedule of K intervals (seconds, ``(K,)``).

        Raises:
            ArgumentError naming ``intervals`` (not a 1-D array of lengths >= 1e-30 s, or a Gramian
            that is numerically singular in the scaled frame: a nearly uncontrollable pair).
        """
        return IntervalMaps(self, intervals)


def check_horizon(model: LinearModel, settling_time: float) -> None:
    """Refuse a model whose free motion outgrows what any law can agree on within the horizon ``T_s`` (seconds).

    Consensus does not stabilise the agents: for ``t >= T_s`` they follow ``e^{A t}`` of the
    weighted initial state (docs: agent-models.md, "Agent models and formations"), so an unstable ``A`` grows
    like ``e^{growth_rate t}`` whatever the controller does, and so does every step's rounding. Up to
    :data:`MAX_HORIZON_GROWTH` (``growth_rate * T_s``) an exact law still agrees to
    ``1e-13 e^{growth_rate T_s}`` or so (:func:`warn_if_unstable` says how far); past it, to nothing.

    Raises:
        ArgumentError naming ``agent_model``, its unstable eigenvalues, its growth rate and ``settling_time``.
    """
    growth = model.growth_rate * settling_time
    if growth > MAX_HORIZON_GROWTH:
        raise ArgumentError(
            f"agent_model: A has unstable eigenvalue(s) {_unstable_eigenvalues(model)} (1/s), so its free motion, and "
            f"every step's rounding with it, grows like e^({model.growth_rate:g} t) (growth rate "
            f"{model.growth_rate:g} 1/s): over settling_time = {settling_time:g} s by e^{growth:.4g}, and rounding "
            f"alone outgrows the disagreement (the exact reference ends near 1e-13 x e^{growth:.4g}); expected growth "
            f"rate x settling_time <= {MAX_HORIZON_GROWTH:g} (a shorter settling_time, or a model that grows more slowly)"
        )


def _unstable_eigenvalues(model: LinearModel) -> str:
    """A's eigenvalues with a positive real part, as text (``1.5, 0.2+1j``)."""
    unstable = [complex(mu) for mu in np.linalg.eigvals(model.A) if mu.real > 0]
    return ", ".join(f"{mu.real:.4g}" + (f"{mu.imag:+.4g}j" if mu.imag else "") for mu in unstable)


class UnstableModelWarning(UserWarning):
    """An agent model with unstable free motion: consensus laws agree, they do not stabilise (:func:`warn_if_unstable`)."""


def warn_if_unstable(model: LinearModel, settling_time: float) -> None:
    """Warn (:class:`UnstableModelWarning`) when ``A`` has eigenvalues with a positive real part, naming them.

    The environment runs such a model (up to :data:`MAX_HORIZON_GROWTH`), as a control library simulates an
    unstable plant: consensus is agreement, and an exact law (the reference) still lands every agent on one
    trajectory by ``T_s``. But that trajectory follows ``e^{A t}`` of the team's weighted initial state, so the
    states grow by up to ``e^{growth_rate T_s}`` whatever the controller does, the rounding with them (the
    exact reference ends near ``1e-13 e^{growth_rate T_s}``), and ``energy_bound`` (E*, a Gramian over the
    whole of ``T_s``) is NaN where that Gramian is singular in float64.
    """
    if model.growth_rate <= 0:
        return
    growth = model.growth_rate * settling_time
    validation.warn_user(
        f"agent_model: A has unstable eigenvalue(s) {_unstable_eigenvalues(model)} (1/s): consensus laws make the "
        f"agents agree, they do not stabilise them; the agreed motion follows e^(A t) and grows by up to "
        f"e^{growth:.3g} = {math.exp(growth):.3g} over settling_time = {settling_time:g} s, and every step's "
        f"rounding with it (an exact law ends near {1e-13 * math.exp(growth):.1g} x D(0)); energy_bound is NaN "
        "where E* over T_s has no float64 value. A stable A keeps the states bounded",
        UnstableModelWarning,
    )


def _times(name: str, value: Any) -> np.ndarray:
    array = _real_matrix(name, value, "a time or an array of times")
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ArgumentError(f"{name}: every time must be finite and >= 0 s")
    return array


# --------------------------------------------------------------------------- formations and final values
def formation_offsets(offsets: Any, n_agents: int, dim: int, n_states: int) -> np.ndarray:
    """Validated formation offsets as full per-axis states, float64 ``(N, dim, n)``.

    Args:
        offsets: ``(N, dim)`` positions (the other state components are zero) or ``(N, dim, n)``
            full states; finite.
        n_agents, dim, n_states: N, the space dimension and n.

    Raises:
        ArgumentError / ArgumentTypeError naming ``formation_offsets``.
    """
    name = "formation_offsets"
    expected = f"an array of shape (N, dim) = ({n_agents}, {dim}) or (N, dim, n) = ({n_agents}, {dim}, {n_states})"
    array = _real_matrix(name, offsets, expected)
    if array.shape == (n_agents, dim):
        full = np.zeros((n_agents, dim, n_states))
        full[..., 0] = array
        array = full
    elif array.shape != (n_agents, dim, n_states):
        raise ArgumentError(f"{name}: expected {expected}, got shape {array.shape}")
    validation.finite_array(name, array)
    return array


def offset_at(h: np.ndarray, F_t: np.ndarray) -> np.ndarray:
    """The offsets carried by free motion to time t: ``e^{A t} h`` with ``F_t = e^{A t}`` ``(n, n)``.

    ``h`` is ``(..., n)`` (e.g. ``(N, dim, n)`` from :func:`formation_offsets`); returns its shape.
    """
    return apply_matrix(np.asarray(F_t, dtype=np.float64), np.asarray(h, dtype=np.float64))


def final_value(model: LinearModel, xi: Any, Z0: Any, t: Any) -> np.ndarray:
    """Consensus value at time t (generalised Theorems 1-2): ``z*(t) = e^{A t} sum_j xi_j z_j(0)``.

    Args:
        model: the agents' :class:`LinearModel`.
        xi: ``(N,)`` or ``(..., N)`` consensus weights (e.g. ``Topology.consensus_weights()``).
        Z0: ``(..., N, dim, n)`` initial states.
        t: time in seconds, >= 0.

    Returns:
        ``(..., dim, n)``, the common state every agent approaches at time t.
    """
    weights = _real_matrix("xi", xi, "an array (..., N)")
    states = _real_matrix("Z0", Z0, "an array (..., N, dim, n)")
    if states.ndim < 3 or states.shape[-1] != model.n_states:
        raise ArgumentError(
            f"Z0: expected an array (..., N, dim, n) with n = {model.n_states}, got shape {states.shape}"
        )
    if weights.ndim < 1 or weights.shape[-1] != states.shape[-3]:
        raise ArgumentError(f"xi: expected an array (..., N) with N = {states.shape[-3]}, got shape {weights.shape}")
    time = validation.real("t", t, minimum=0.0)
    mean = np.einsum("...j,...jdn->...dn", weights, states)
    return apply_matrix(model.free_motion_matrix(time), mean)
