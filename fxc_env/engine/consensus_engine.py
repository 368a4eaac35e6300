"""The batched consensus engine: B independent episodes of N double-integrator agents.

This is the one code path behind every front end: the PettingZoo environment is the
``n_episodes = 1`` case, the SB3 VecEnv and :func:`fxc_env.simulate` use larger batches,
and the TorchRL environment (:mod:`fxc_env.envs.torch_env`) runs it on torch tensors. Arrays
are numpy arrays (``device=None``, the default) or torch tensors on ``device`` (``"cpu"``,
``"cuda"``, ``"meta"``), float64 by default: positions ``x`` and velocities ``v`` are
``(B, N, dim)``; observations ``(B, N, obs_size)``; actions ``(B, N, 2 dim)``.

One step integrates the affine input on ``[t_k, t_{k+1})`` in closed form
(:mod:`fxc_env.core.dynamics`), clipped to ``±u_max`` when that is set. Measurement noise,
link dropout and random switching draw from :attr:`ConsensusEngine.rng` (a numpy
``Generator``, or a ``torch.Generator`` on the device), which the front ends seed; each
sampling instant's measurements are drawn once and cached.

**One code path over numpy and torch.** Every step is written against the Python array API
(:mod:`fxc_env.core.arrays`); the few numpy-only fast paths (marked "numpy fast path", each
measured to pay on 2 cores) sit next to the generic lines they replace and compute the same
values. Random draws are the one backend-specific piece (:meth:`ConsensusEngine._uniform`,
:meth:`ConsensusEngine._normal`).

**Clocks.** Episodes start together and advance in lock step (a host counter ``k``) until a
partial reset (``reset(..., episodes=mask)``) restarts some of them: from then on every
episode has its own instant ``steps`` ``(B,)`` on the device, and its interval length, clock
features and graph are gathered per episode.

**Where a bad value is reported.** On numpy a step whose result would not be finite is
refused at once (:class:`ArgumentError` naming ``actions``, state unchanged). On torch the
step never reads a value back to the host: non-finite actions or results, and stepping an
episode past ``T_s``, set a per-episode flag on the device (:attr:`ConsensusEngine.invalid`),
read by :meth:`ConsensusEngine.raise_if_invalid` off the hot path (the TorchRL environment
calls it at every reset and at the end of every episode; ``check_values=False`` leaves it to
the caller).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core import dynamics, slots, validation
from fxc_env.core.arrays import namespace
from fxc_env.core.graphs import DENSE_LIMIT, Topology
from fxc_env.core.metrics import (
    SETTLING_THRESHOLDS,
    EpisodeMetrics,
    disagreement,
    reward_floor,
    spread,
)
from fxc_env.core.validation import ArgumentError

TINY = np.finfo(np.float64).tiny
#: Array dtypes the engine computes in (float32: see the TorchRL environment's card for its floor).
DTYPES = ("float64", "float32")


@dataclass(frozen=True)
class EpisodeDraw:
    """What one episode drew at reset: its initial state ``(N, dim)`` each, and, where the
    config asks for a draw, its topology (a family) and its input limit (a set of ``u_max``)."""

    x0: np.ndarray
    v0: np.ndarray
    topology: Topology | None = None
    u_max: float | None = None


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
    adds ``T_s^2 e_a``; a single integrator has ``e_x`` alone.
    """
    total = None
    for component in range(states.shape[-2]):
        term = (config.settling_time**component) * spread(states[..., component, :])
        total = term if total is None else total + term
    return total


def limit_feature(u_max: Any, interval: Any, scale: Any) -> Any:
    """How far the input limit binds on the coming interval, scale-free, in ``[-1, 1]``.

    ``rho = u_max T^2 / s_i`` compares the limit with the input a plan at agent i's scale
    needs: the paper's controller starts an interval at about ``6 e / T^2`` (eq. 11), at
    most ``10 s_i / T^2``, so ``rho`` below about 10 means the limit cuts the planned
    input and ``rho >> 10`` that it is out of reach. The feature is ``l / (1 + |l|)`` with
    ``l = log10(rho)``: decades spread evenly (0 at ``rho = 1``, ±0.5 one decade either
    side, ±0.75 three), bounded without a hard clip; ``s_i = 0`` (nothing to correct) gives
    1. Scaling the state and ``u_max`` by the same factor leaves it unchanged. Shape of
    ``scale``, e.g. ``(B, N)``; numpy arrays or torch tensors.
    """
    xp = namespace(scale)
    with np.errstate(divide="ignore", invalid="ignore"):
        decades = xp.log10(u_max * interval * interval) - xp.log10(scale)
        return xp.where(xp.isfinite(decades), decades / (1.0 + xp.abs(decades)), xp.ones_like(decades))


def _weighted_sum(values: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``xi^T values`` per episode: ``values`` ``(B, N)``, ``xi`` ``(N,)`` or ``(B, N)``."""
    return values @ xi if xi.ndim == 1 else np.einsum("bn,bn->b", values, xi)


def _draw_scale(half_widths: tuple[float, float], rng: np.random.Generator) -> float:
    """``low`` when the range is one number, else a log-uniform draw from ``[low, high]``."""
    low, high = half_widths
    return low if low == high else float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _backend(device: Any) -> tuple[Any, Any]:
    """``(torch device or None, array namespace)`` for ``device`` (None: numpy)."""
    if device is None:
        return None, namespace(np.empty(0))
    import torch  # the torch backend only: a numpy user never imports torch here

    try:
        chosen = torch.device(device)
    except (RuntimeError, TypeError) as error:
        raise ArgumentError(
            f"device: expected None (numpy) or a torch device such as 'cpu' or 'cuda', got {device!r}"
        ) from error
    if chosen.type == "cuda" and not torch.cuda.is_available():
        raise ArgumentError(f"device: {device!r} asks for CUDA, but torch.cuda.is_available() is False on this machine")
    return chosen, namespace(torch.empty(0, device=chosen))


def to_host(array: Any) -> np.ndarray:
    """A numpy copy (or the array itself) of a numpy array or a torch tensor: a read off the device."""
    if isinstance(array, np.ndarray):
        return array
    return array.detach().cpu().numpy()


class ConsensusEngine:
    """B episodes advanced as arrays. Call :meth:`reset` before :meth:`step`.

    Args:
        config: the environment's settings (:func:`fxc_env.config.make_config`).
        n_episodes: the batch size B.
        device: None for numpy arrays (the default), else a torch device (``"cpu"``,
            ``"cuda"``, ``"cuda:1"``, ``"meta"``) on which every array lives.
        dtype: ``"float64"`` (the default; the deadline error lives near 1e-12) or ``"float32"``.
    """

    def __init__(self, config: EnvConfig, n_episodes: int = 1, *, device: Any = None, dtype: str = "float64") -> None:
        self.config = config
        self.n_episodes = int(n_episodes)
        self.layout = config.layout
        self.device, self.xp = _backend(device)
        #: numpy arrays, where the numpy fast paths apply.
        self.is_numpy = self.device is None
        xp = self.xp
        self.dtype = getattr(xp, validation.choice("dtype", dtype, DTYPES))
        self._tiny = float(np.finfo(dtype).tiny)
        n, dim, b = config.n_agents, config.dim, self.n_episodes
        shape = (b, n, dim)
        #: ``(B, N, 2, dim)``: ``state[:, :, 0]`` positions, ``state[:, :, 1]`` velocities,
        #: side by side so one gather fetches both of a neighbour's values.
        n_states = config.n_states
        if config.model is not None and not self.is_numpy:
            raise ArgumentError(
                f"device: {config.agent_model!r} agents run on numpy (device=None) in this version; the torch "
                "backend covers the double integrator"
            )
        self.state = self._zeros((b, n, n_states, dim))
        self._spare = self._zeros((b, n, n_states, dim)) if self.is_numpy else None
        self.x0 = self._zeros(shape)
        self.v0 = self._zeros(shape)
        #: Lock-step instant index (host), valid while :attr:`steps` is None.
        self.k = 0
        #: Each episode's own instant index ``(B,)`` after a partial reset, else None (all at ``k``).
        self.steps: Any = None
        self._tick = 0
        self._episode_index = xp.reshape(xp.arange(b, device=self.device), (b, 1, 1))
        #: Each episode's topology (a family draws new ones at every reset, see :meth:`reset`).
        self.topologies: list[Topology] = [config.topology] * b
        self._set_graph_table(self.topologies)
        #: Each episode's input limit ``u_max`` (m/s^2), ``(B,)``, or None without a limit.
        self.u_max: Any = None if config.u_max_choices is None else self._full(b, config.u_max_choices[0])
        schedule = config.schedule
        k_all = np.arange(schedule.n_intervals + 1)
        next_interval = schedule.intervals[np.minimum(k_all, schedule.n_intervals - 1)]
        #: Clock features of every sampling instant: ``t_k / T_s, T_{k+1} / T_s, k / K``, ``(K + 1, 3)``.
        clock = np.stack([schedule.times, next_interval, 0 * k_all], axis=1) / schedule.settling_time
        clock[:, 2] = k_all / schedule.n_intervals
        self._clock = self._array(clock)
        self._next_interval = next_interval.tolist()
        self._next_interval_array = self._array(next_interval)
        #: Per instant, what each flat row entry is multiplied by before the division by s:
        #: 1 for position parts, ``T_{k+1}`` for velocity parts, ``(K + 1, slots * 2 dim)``.
        per_row = np.repeat(config.row_scales, config.dim, axis=1)
        self._row_factors = self._array(np.tile(per_row, self.layout.slots))
        #: Per instant, what each state component is multiplied by to read in position units, ``(K + 1, n)``.
        self._row_scales = self._array(config.row_scales)
        #: Formation offsets ``h`` ``(N, n, dim)`` (the engine plays ``zeta = z - e^{A t} h``), or None.
        self._formation = None if config.formation is None else self._array(config.formation)
        self._formation_motion = None if config.formation is None else self._array(config.formation_motion)
        #: The initial state in the engine's coordinates ``(B, N, n, dim)``.
        self.z0 = self._zeros((b, n, n_states, dim))
        #: Settling thresholds as a column, ``(len(SETTLING_THRESHOLDS), 1)``.
        self._thresholds = self._array(np.array(SETTLING_THRESHOLDS)[:, None])
        #: Generator of measurement noise, link dropout and random switching.
        self.rng: Any = np.random.default_rng() if self.is_numpy else self._torch_generator(None)
        self._no_saturation = self._zeros((b, n))
        self._range_weights = np.array([1.0, config.settling_time])
        #: Per episode: a non-finite action or result, or a step past ``T_s``, was seen (torch only;
        #: numpy refuses such a step at once). Read by :meth:`raise_if_invalid`.
        self.invalid = None if self.is_numpy else xp.zeros(b, dtype=xp.bool, device=self.device)
        self._reset_trackers()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["xp"]  # a module: found again from the device on unpickling
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.xp = _backend(self.device)[1]

    # ------------------------------------------------------------ arrays
    def _array(self, values: Any, dtype: Any = None) -> Any:
        """``values`` (numpy or a number) as an array of this engine's backend, dtype and device."""
        dtype = self.dtype if dtype is None else dtype
        if self.is_numpy:
            return np.asarray(values, dtype=dtype)
        return self.xp.asarray(np.array(values), dtype=dtype, device=self.device)

    def _zeros(self, shape: tuple[int, ...]) -> Any:
        return self.xp.zeros(shape, dtype=self.dtype, device=self.device)

    def _full(self, shape: Any, value: float) -> Any:
        return self.xp.full(shape, value, dtype=self.dtype, device=self.device)

    def _torch_generator(self, seed: int | None) -> Any:
        """A ``torch.Generator`` on the device (None on ``meta``, which draws shapes only)."""
        import torch

        if self.device.type == "meta":
            return None
        generator = torch.Generator(device=self.device)
        if seed is None:
            generator.seed()
        else:
            generator.manual_seed(int(seed))
        return generator

    def seed(self, seed: int | None) -> None:
        """Seed :attr:`rng` (noise, dropout, switching and, on torch, :meth:`draw_batch`)."""
        self.rng = np.random.default_rng(seed) if self.is_numpy else self._torch_generator(seed)

    def _uniform(self, shape: tuple[int, ...]) -> Any:
        """Uniform draws on ``[0, 1)`` from :attr:`rng`, on the device (the backend-specific part)."""
        if self.is_numpy:
            return self.rng.random(shape)
        import torch

        return torch.rand(shape, generator=self.rng, dtype=self.dtype, device=self.device)

    def _normal(self, shape: tuple[int, ...]) -> Any:
        """Standard normal draws from :attr:`rng`, on the device."""
        if self.is_numpy:
            return self.rng.standard_normal(shape)
        import torch

        return torch.randn(shape, generator=self.rng, dtype=self.dtype, device=self.device)

    def _switching_draw(self, periods: Any) -> Any:
        """Random switching: each episode's graph index on the coming interval, uniform in ``[0, m_b)``."""
        if self.is_numpy and self._shared_topology:
            return self.rng.integers(0, int(periods[0]), self.n_episodes)
        local = self.xp.floor(self._uniform((self.n_episodes,)) * self.xp.astype(periods, self.dtype))
        return self.xp.astype(local, self.xp.int64)

    # ------------------------------------------------------------------ state
    @property
    def x(self) -> Any:
        """Positions ``(B, N, dim)`` at ``t_k`` (a view of :attr:`state`)."""
        return self.state[:, :, 0]

    @property
    def v(self) -> Any:
        """Velocities ``(B, N, dim)`` at ``t_k`` (a view of :attr:`state`; zeros for a single integrator)."""
        if self.config.n_states == 1:
            return self.xp.zeros_like(self.state[:, :, 0])
        return self.state[:, :, 1]

    def absolute_state(self) -> Any:
        """The agents' states ``(B, N, n, dim)`` at ``t_k``: :attr:`state` plus ``e^{A t_k} h`` with formation offsets.

        The engine plays the formation error ``zeta_i = z_i - e^{A t} h_i``: the offsets'
        trajectory is a free motion (no input), so ``zeta`` obeys the same dynamics under the
        same inputs, and consensus of ``zeta`` is the formation. Without offsets this is :attr:`state`.
        """
        if self._formation is None:
            return self.state
        xp = self.xp
        motion = self._per_instant(xp.reshape(self._formation_motion, (self.config.n_intervals + 1, -1)))
        n = self.config.n_states
        motion = xp.reshape(motion, (*motion.shape[:-1], n, n))  # (n, n) or (B, 1, n, n)
        return self.state + motion @ self._formation

    def sample_initial_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One episode's ``(x0, v0)`` (numpy): the config's initial state, else uniform draws.

        Positions are drawn from ``U(-a, a)`` and velocities from ``U(-b, b)`` per component,
        with ``a = position_range`` and ``b = velocity_range`` (defaults 5 m and 2 m/s). A
        ``(low, high)`` range first draws the half-width log-uniformly, so episodes span
        decades of scale.
        """
        c = self.config
        if c.initial_state is not None:
            return c.initial_state[0].copy(), c.initial_state[1].copy()
        shape = (c.n_agents, c.dim)
        position_range = _draw_scale(c.position_range, rng)
        velocity_range = _draw_scale(c.velocity_range, rng)
        x0 = rng.uniform(-position_range, position_range, size=shape)
        v0 = rng.uniform(-velocity_range, velocity_range, size=shape)
        return x0, v0

    def draw_episode(self, rng: np.random.Generator) -> EpisodeDraw:
        """What a new episode draws from its seeded numpy generator, in this order.

        Its topology when the config has a family, its input limit when ``u_max`` is a set,
        then ``(x0, v0)`` (:meth:`sample_initial_state`). A config with none of these draws
        exactly what it always did, so seeds keep their episodes.
        """
        c = self.config
        topology = None if c.family is None else c.family.draw(c.n_agents, rng)
        choices = c.u_max_choices
        u_max = None if choices is None else choices[0] if len(choices) == 1 else float(rng.choice(choices))
        x0, v0 = self.sample_initial_state(rng)
        return EpisodeDraw(x0, v0, topology, u_max)

    def draw_batch(self, host_rng: np.random.Generator | None = None) -> tuple[Any, Any, Any, list | None]:
        """Every episode's draw at once, on the device, from :attr:`rng`: ``(x0, v0, u_max, topologies)``.

        The same distributions as :meth:`draw_episode` (the half-widths log-uniform when given
        as ranges, then uniform states; ``u_max`` uniform over the set), ``(B, N, dim)`` each
        and ``(B,)`` (None without a limit). A topology family is the one draw made on the host
        (``host_rng``; graphs are built and checked there, once per episode, never per step);
        ``topologies`` is None without one.
        """
        c, xp, b = self.config, self.xp, self.n_episodes
        shape = (b, c.n_agents, c.dim)
        if c.initial_state is not None:
            x0 = self._array(np.broadcast_to(c.initial_state[0], shape))
            v0 = self._array(np.broadcast_to(c.initial_state[1], shape))
        else:
            x0 = (2.0 * self._uniform(shape) - 1.0) * self._half_widths(c.position_range)
            v0 = (2.0 * self._uniform(shape) - 1.0) * self._half_widths(c.velocity_range)
        u_max = None
        if c.u_max_choices is not None:
            choices = self._array(c.u_max_choices)
            pick = xp.astype(xp.floor(self._uniform((b,)) * len(c.u_max_choices)), xp.int64)
            u_max = xp.take(choices, xp.clip(pick, 0, len(c.u_max_choices) - 1), axis=0)
        topologies = None
        if c.family is not None:
            rng = np.random.default_rng() if host_rng is None else host_rng
            topologies = [c.family.draw(c.n_agents, rng) for _ in range(b)]
        return x0, v0, u_max, topologies

    def _half_widths(self, half_widths: tuple[float, float]) -> Any:
        """``(B, 1, 1)`` half-widths: the number, or log-uniform draws from ``[low, high]``."""
        low, high = half_widths
        if low == high:
            return low
        unit = self._uniform((self.n_episodes, 1, 1))
        return self.xp.exp(math.log(low) + unit * (math.log(high) - math.log(low)))

    def reset(
        self,
        x0: Any,
        v0: Any,
        rng: Any = None,
        *,
        topologies: Sequence[Topology | None] | None = None,
        u_max: Any = None,
        episodes: Any = None,
    ) -> None:
        """Start episodes at ``t_0 = 0`` from ``x0, v0`` of shape ``(B, N, dim)``.

        ``rng`` (optional) replaces :attr:`rng`, the generator of noise, dropout and random
        switching; without it the current generator goes on. ``topologies`` (one per
        episode; None keeps the config's) and ``u_max`` (one per episode) come from
        :meth:`draw_episode` / :meth:`draw_batch`; without them every episode uses the config's.

        ``episodes`` (a ``(B,)`` boolean array on the device) restarts only those episodes
        (TorchRL's partial reset): their rows of ``x0, v0, u_max`` and ``topologies`` are used,
        the others go on where they are; from then on every episode keeps its own clock.
        """
        xp = self.xp
        if episodes is not None and self.config.model is not None:
            raise ArgumentError(
                f"episodes: partial resets are for the double integrator, not {self.config.agent_model!r} agents"
            )
        if topologies is not None:
            chosen = [self.config.topology if t is None else t for t in topologies]
            if any(a is not b for a, b in zip(chosen, self.topologies, strict=True)):
                self.topologies = chosen
                self._set_graph_table(chosen)
        if u_max is not None and self.u_max is not None:
            if isinstance(u_max, Sequence) and not hasattr(u_max, "shape"):
                u_max = [self.config.u_max_choices[0] if u is None else u for u in u_max]
            given = self._array(u_max) if self.is_numpy or isinstance(u_max, np.ndarray | list) else u_max
            self.u_max = given if episodes is None else xp.where(episodes, given, self.u_max)
        if rng is not None:
            self.rng = rng
        if not self.is_numpy:
            x0 = self._array(x0) if isinstance(x0, np.ndarray) else x0
            v0 = self._array(v0) if isinstance(v0, np.ndarray) else v0
        fresh = self._initial_coordinates(x0, v0)
        if episodes is None:
            self.state[...] = fresh
            self.z0[...] = fresh
            self.x0[...] = x0
            self.v0[...] = v0
            self.k = 0
            self.steps = None
        else:
            keep = xp.reshape(episodes, (-1, 1, 1))
            self.x0 = xp.where(keep, x0, self.x0)
            self.v0 = xp.where(keep, v0, self.v0)
            self.state = xp.where(xp.reshape(episodes, (-1, 1, 1, 1)), fresh, self.state)
            self.z0 = xp.where(xp.reshape(episodes, (-1, 1, 1, 1)), fresh, self.z0)
            current = self._episode_steps()
            self.steps = xp.where(episodes, xp.zeros_like(current), current)
            if self.invalid is not None:
                self.invalid = xp.where(episodes, xp.zeros_like(self.invalid), self.invalid)
        if episodes is None and self.invalid is not None:
            self.invalid = xp.zeros_like(self.invalid)
        self._reset_trackers(episodes)

    def _initial_coordinates(self, x0: Any, v0: Any) -> Any:
        """The engine's state ``(B, N, n, dim)`` for initial positions and velocities ``(B, N, dim)``.

        Higher state components (a chain's acceleration, ...) start at 0; a single integrator
        has no velocity (``v0`` is not used). With formation offsets, ``h`` is subtracted (t = 0).
        """
        xp, n = self.xp, self.config.n_states
        parts = [x0, v0][:n] + [xp.zeros_like(x0)] * (n - 2)
        fresh = xp.stack(parts, axis=2)
        return fresh if self._formation is None else fresh - self._formation

    def validate_state(self, name: str, value: object) -> np.ndarray:
        """A user-given ``(N, dim)`` state array, checked (see :func:`fxc_env.core.validation.state_array`)."""
        return validation.state_array(name, value, self.config.n_agents, self.config.dim)

    def _episode_steps(self) -> Any:
        """Each episode's instant index ``(B,)`` on the device."""
        if self.steps is not None:
            return self.steps
        return self.xp.full((self.n_episodes,), self.k, dtype=self.xp.int64, device=self.device)

    def _reset_trackers(self, episodes: Any = None) -> None:
        xp = self.xp
        b, n = self.n_episodes, self.config.n_agents
        fresh = self._disagreement()
        floor = reward_floor(fresh, self.config.reward_floor)
        inverse_d0 = 1.0 / xp.where(fresh > 0, fresh, xp.ones_like(fresh))
        inverse_d0 = xp.where(fresh > 0, inverse_d0, xp.zeros_like(fresh))
        log_disagreement = xp.log(fresh + floor)
        last_above = xp.zeros((len(SETTLING_THRESHOLDS), b), dtype=xp.int64, device=self.device)
        if episodes is None:
            self.initial_disagreement = fresh
            self.current_disagreement = xp.asarray(fresh, copy=True)
            self.floor = floor
            self._log_disagreement = log_disagreement
            self._inverse_d0 = inverse_d0
            self.energy_total = self._zeros((b, n))
            self.peak_total = self._zeros((b, n))
            # Index of the last sampling instant whose D(t_k)/D(0) was >= eps, per threshold.
            self.last_above = last_above
            self.saturated_time = self._zeros((b, n))
        else:
            per_agent = xp.reshape(episodes, (-1, 1))
            self.initial_disagreement = xp.where(episodes, fresh, self.initial_disagreement)
            self.current_disagreement = xp.where(episodes, fresh, self.current_disagreement)
            self.floor = xp.where(episodes, floor, self.floor)
            self._log_disagreement = xp.where(episodes, log_disagreement, self._log_disagreement)
            self._inverse_d0 = xp.where(episodes, inverse_d0, self._inverse_d0)
            self.energy_total = xp.where(per_agent, xp.zeros_like(self.energy_total), self.energy_total)
            self.peak_total = xp.where(per_agent, xp.zeros_like(self.peak_total), self.peak_total)
            self.last_above = xp.where(episodes, last_above, self.last_above)
            self.saturated_time = xp.where(per_agent, xp.zeros_like(self.saturated_time), self.saturated_time)
        self._tick += 1
        self._measured: tuple | None = None
        self._draw_graphs()

    @property
    def done(self) -> bool:
        """The deadline has been reached: ``t_k = T_s`` (lock step; see :meth:`episode_done` after a partial reset)."""
        if self.steps is not None:
            raise RuntimeError("done: episodes keep their own clocks since a partial reset; use episode_done()")
        return self.k >= self.config.schedule.n_intervals

    def episode_done(self) -> Any:
        """Per episode, whether it reached ``T_s``: ``(B,)`` booleans on the device."""
        return self._episode_steps() >= self.config.schedule.n_intervals

    @property
    def time(self) -> float:
        """Current sampling instant ``t_k`` in seconds (lock step)."""
        return float(self.config.schedule.times[self.k])

    def current_interval(self) -> float:
        """Length ``T = t_{k+1} - t_k`` of the interval about to be played (seconds, lock step)."""
        return self._next_interval[self.k]

    def _interval(self, trailing: int) -> Any:
        """The coming interval length: a number in lock step, else ``(B, 1, ...)`` with ``trailing`` ones."""
        if self.steps is None:
            return self._next_interval[self.k]
        lengths = self.xp.take(self._next_interval_array, self.steps, axis=0)
        return self.xp.reshape(lengths, (-1,) + (1,) * trailing)

    def _per_instant(self, table: Any) -> Any:
        """Row of a ``(K + 1, F)`` table at the current instant: ``(F,)`` in lock step, else ``(B, 1, F)``."""
        if self.steps is None:
            return table[self.k]
        return self.xp.take(table, self.steps, axis=0)[:, None, :]

    def graph_indices(self) -> Any:
        """Index, within its own topology, of each episode's graph on the current interval, ``(B,)``."""
        return self._graph_ids - self._graph_offset

    def _set_graph_table(self, topologies: Sequence[Topology]) -> None:
        """Stack every episode's graphs into one table of neighbour slots, padded to the layout's width.

        ``_neighbour_index`` and ``_mask_features`` are ``(G, N, slots)`` over the G distinct
        graphs; episode b uses rows ``_graph_offset[b] + (0 .. m_b - 1)``. Extra slots point
        at the agent itself (a gather then gives exact zeros) and are masked out. Built on
        the host (at construction and when a family draws new graphs) and copied once.
        """
        n, slot_count = self.config.n_agents, self.layout.slots
        unique: dict[int, int] = {}
        index_blocks, mask_blocks, offsets, periods = [], [], [], []
        start = 0
        for topology in topologies:
            if id(topology) not in unique:
                unique[id(topology)] = start
                extra = slot_count - topology.max_in_degree
                own = np.broadcast_to(np.arange(n)[None, :, None], (topology.period, n, extra))
                index_blocks.append(np.concatenate([topology.neighbour_index, own], axis=2))
                mask_blocks.append(
                    np.concatenate([topology.neighbour_mask, np.zeros((topology.period, n, extra), bool)], axis=2)
                )
                start += topology.period
            offsets.append(unique[id(topology)])
            periods.append(topology.period)
        self._neighbour_index = self._array(np.concatenate(index_blocks), dtype=self.xp.int64)
        self._mask_features = self._array(np.concatenate(mask_blocks))
        self._graph_offset_host = np.array(offsets)
        self._graph_period_host = np.array(periods)
        self._graph_offset = self._array(self._graph_offset_host, dtype=self.xp.int64)
        self._graph_period = self._array(self._graph_period_host, dtype=self.xp.int64)
        #: One topology for all episodes: gathers take the fast path of a single graph.
        self._shared_topology = len(unique) == 1

    def _draw_graphs(self) -> None:
        """Each episode's graph on the coming interval: ``G_{k mod m}``, or a uniform draw (random switching)."""
        random = self.config.switching == "random"
        self._same_graph = self._shared_topology and not random and self.steps is None
        if self._same_graph:
            # One graph for every episode, known on the host.
            self._graph = int(self._graph_offset_host[0] + self.k % self._graph_period_host[0])
        if random:
            local = self._switching_draw(self._graph_period_host if self.is_numpy else self._graph_period)
        elif self.steps is None:
            local = self.k % (self._graph_period_host if self.is_numpy else self._graph_period)
        else:
            local = self.steps % self._graph_period
        self._graph_ids = (self._graph_offset_host if self.is_numpy else self._graph_offset) + local

    # ------------------------------------------------------------ observation
    def measurements(self) -> tuple[Any, Any, Any]:
        """What the agents measure at ``t_k``, in metres and m/s, drawn once per instant.

        Returns:
            rows ``(B, N, slots, 2, dim)``: ``[x_j - x_i, v_j - v_i]`` per in-neighbour slot
            (padded slots point at i itself and hold exact zeros), with noise and dropout;
            mask ``(B, N, slots)`` or ``(N, slots)`` (1 for a row received); and the local scale
            ``s_i = max(|x_j - x_i|, T |v_j - v_i|)`` over the rows, ``(B, N)``.
        """
        if self._measured is not None and self._measured[0] == self._tick:
            return self._measured[1:]
        c, xp = self.config, self.xp
        if self._same_graph:
            # Gather [x_j, v_j] together (one random access per edge).
            if self.is_numpy:  # numpy fast path: take with mode="clip" skips the bounds check (1.3x)
                rows = np.take(self.state, self._neighbour_index[self._graph], axis=1, mode="clip")
            else:
                rows = self.state[:, self._neighbour_index[self._graph]]
            mask = self._mask_features[self._graph]
        else:
            index = self._neighbour_index[self._graph_ids]  # (B, N, slots)
            rows = self.state[self._episode_index, index]
            mask = self._mask_features[self._graph_ids]
        rows -= self.state[:, :, None]
        if c.link_dropout > 0:
            mask = mask * xp.astype(self._uniform((self.n_episodes, *mask.shape[-2:])) >= c.link_dropout, self.dtype)
            rows *= mask[..., None, None]
        if c.obs_noise > 0:
            rows += (c.obs_noise * mask[..., None, None]) * self._normal(tuple(rows.shape))
        T = self._interval(1)
        if self.config.model is not None:
            # General agents: the largest |z_j - z_i| per component in position units (row_scales).
            largest = (
                xp.max(xp.abs(rows), axis=(-3, -1))
                if self.layout.slots
                else self._zeros((*rows.shape[:-3], self.config.n_states))
            )
            scale = xp.max(largest * self._per_instant(self._row_scales), axis=-1)
            self._measured = (self._tick, rows, mask, scale)
            return rows, mask, scale
        if self.is_numpy:  # numpy fast path: a loop over the few slot columns (3x, see core.slots)
            largest = slots.max_abs_rows(rows)
        elif self.layout.slots:
            largest = xp.max(xp.abs(rows), axis=(-3, -1))
        else:
            largest = self._zeros((*rows.shape[:-3], 2))
        scale = xp.maximum(largest[..., 0], T * largest[..., 1])
        self._measured = (self._tick, rows, mask, scale)
        return rows, mask, scale

    def observations(self, out: np.ndarray | None = None) -> Any:
        """Every agent's flat observation at ``t_k``, ``(B, N, obs_size)`` (the card's Observation Space).

        ``out`` (optional, numpy, ``(B, N, obs_size)`` float64) is filled instead of a fresh
        array: for loops that consume observations at once, it saves the page faults of
        a new large buffer every step. In normalized mode the rows are divided by the local
        scale; division (not multiplication by ``1/s``) keeps every entry within [-1, 1].
        """
        c, layout, xp = self.config, self.layout, self.xp
        b, n = self.n_episodes, c.n_agents
        raw, mask, scale = self.measurements()
        normalized = c.obs_mode == "normalized" and layout.slots
        if self.is_numpy and self.steps is None:
            obs = np.empty((b, n, layout.size)) if out is None else out
            if normalized:
                # numpy fast path: whole rows at once into the output, x parts times 1 and v parts
                # times T, then over s (numpy's inner loops over an agent's whole row: 3x at dim = 2).
                np.multiply(raw.reshape(b, n, -1), self._row_factors[self.k], out=obs[..., : layout.rows_end])
                obs[..., : layout.rows_end] /= np.maximum(scale, TINY)[:, :, None]
            else:
                obs[..., : layout.rows_end] = raw.reshape(b, n, -1)
            obs[..., layout.rows_end : layout.mask_end] = mask
            obs[..., layout.mask_end : layout.clock_end] = self._clock[self.k]
            if layout.limit_feature:
                obs[..., layout.clock_end] = limit_feature(self.u_max[:, None], self.current_interval(), scale)
            return obs
        rows = xp.reshape(raw, (b, n, -1))
        if normalized:
            # s = 0 only when every row is 0; the floor keeps 0 / s at 0 without a branch.
            rows = (
                rows * self._per_instant(self._row_factors) / xp.maximum(scale, self._full((), self._tiny))[..., None]
            )
        zeros = self._zeros((b, n, 1))
        parts = [rows, mask + zeros, self._per_instant(self._clock) + zeros]
        if layout.limit_feature:
            parts.append(limit_feature(self.u_max[:, None], self._interval(1), scale)[..., None])
        return xp.concat(parts, axis=-1)

    def local_scale(self) -> Any:
        """Each agent's local scale ``s_i`` at ``t_k`` (metres), ``(B, N)``; 0 if it sees no disagreement."""
        return self.measurements()[2]

    def normalized_state(self) -> Any:
        """The scale-free global state of every episode, ``(B, N * n dim + 3)``, on the device.

        Per agent the row ``[z_i - mean_j z_j]`` component by component, component l times
        ``T_s^l`` (``[x_i - x̄, T_s (v_i - v̄)]`` for the double integrator), over
        ``max(D, tiny)``, agent major; then the clock ``t_k / T_s, T_{k+1} / T_s, k / K``. Every
        row entry is at most ``D`` in magnitude, so the rows lie in [-1, 1] by construction
        (clipped there only against rounding) and are all zero when ``D = 0``: invariant to a
        common shift and to the scale, like the normalized observations. For centralised critics.
        """
        xp, c = self.xp, self.config
        z = self.state
        components = [
            (c.settling_time**i) * (z[:, :, i] - xp.mean(z[:, :, i], axis=1, keepdims=True)) for i in range(c.n_states)
        ]
        rows = xp.concat(components, axis=-1) / xp.reshape(
            xp.maximum(self.current_disagreement, self._full((), self._tiny)), (-1, 1, 1)
        )
        rows = xp.reshape(xp.clip(rows, -1.0, 1.0), (self.n_episodes, -1))
        clock = self._per_instant(self._clock)
        clock = xp.reshape(clock, (-1, clock.shape[-1])) + self._zeros((self.n_episodes, 1))
        return xp.concat([rows, clock], axis=-1)

    # ----------------------------------------------------------------- action
    def validate_actions(self, actions: object, name: str = "actions") -> Any:
        """A ``(B, N, 2 dim)`` real, finite action array; raise naming ``name`` otherwise.

        numpy: checked in full at once. torch: the shape and dtype are checked at once (they
        are known on the host); a non-finite entry sets :attr:`invalid` on the device (read
        by :meth:`raise_if_invalid`), so the check never waits on the device.
        """
        expected = (self.n_episodes, self.config.n_agents, self.config.action_size)
        if self.is_numpy:
            return validation.action_array(name, actions, expected)
        xp = self.xp
        if not hasattr(actions, "shape") or not hasattr(actions, "device"):
            raise ArgumentError(f"{name}: expected a torch tensor of shape {expected}, got {type(actions).__name__}")
        if tuple(actions.shape) != expected:
            raise ArgumentError(f"{name}: expected shape {expected}, got {tuple(actions.shape)}")
        if not xp.isdtype(actions.dtype, ("real floating", "integral")):
            raise ArgumentError(f"{name}: expected real numbers, got dtype {actions.dtype}")
        actions = xp.astype(actions, self.dtype)
        self.invalid = self.invalid | ~xp.all(xp.isfinite(actions), axis=(1, 2))
        return actions

    def raise_if_invalid(self) -> None:
        """Raise :class:`ArgumentError` if any episode saw a non-finite action or result (torch: one read off the device)."""
        if self.invalid is None:
            return
        bad = np.flatnonzero(to_host(self.invalid))
        if len(bad):
            raise ArgumentError(
                f"actions: episodes {bad[:10].tolist()} received a non-finite action, overflowed float64 or were "
                "stepped past T_s since their last reset; reset them (their states are not to be trusted)"
            )

    def inputs_from_actions(self, actions: Any) -> tuple[Any, Any]:
        """Map actions to the affine input's end values ``(u(t_k+), u(t_{k+1}-))`` (the card's Action Space)."""
        c, dim = self.config, self.config.dim
        T = self._interval(2)
        first, second = actions[..., :dim], actions[..., dim:]
        if c.obs_mode == "normalized":
            s = self.local_scale()[..., None]
            if c.action_mode == "plan":
                return dynamics.input_from_plan(s * first, (s / T) * second, T)
            gain = s / (T * T)
            return gain * first, gain * second
        if c.action_mode == "plan":
            return dynamics.input_from_plan(first, second, T)
        return first, second

    def step(self, actions: Any) -> StepOutcome:
        """Play one interval with already validated ``(B, N, 2 dim)`` actions."""
        xp = self.xp
        lock_step = self.steps is None
        if lock_step and self.done:
            raise RuntimeError("step: the episode reached T_s; reset before stepping again")
        T = self._interval(2)
        u_max = self.u_max
        with np.errstate(over="ignore", invalid="ignore"):
            saturated_time = None
            if self.config.model is not None:
                state_next, energy, peak, u0, u1, plan = self._steer(actions)
                x_next = v_next = None
            elif u_max is not None:
                u0, u1 = self.inputs_from_actions(actions)
                x_next, v_next, energy, peak, saturated_time = dynamics.advance_clipped(
                    self.x, self.v, u0, u1, T, u_max[:, None, None]
                )
            elif self.is_numpy and lock_step:
                # numpy fast path: the closed forms written into the spare buffer (no temporaries).
                u0, u1 = self.inputs_from_actions(actions)
                x_next, v_next = self._spare[:, :, 0], self._spare[:, :, 1]
                energy, peak = dynamics.advance_into(self.x, self.v, u0, u1, T, x_next, v_next)
            else:
                u0, u1 = self.inputs_from_actions(actions)
                x_next, v_next, energy, peak = dynamics.advance_with_costs(self.x, self.v, u0, u1, T)
            previous = self.state
            if self.is_numpy:
                # Double buffering: the interval is played into the spare buffer, which becomes the
                # state only once the result is known to be finite (a refused step changes nothing).
                following = self._spare
                if x_next is None:
                    following[...] = state_next
                elif x_next is not following[:, :, 0]:
                    following[:, :, 0] = x_next
                    following[:, :, 1] = v_next
                self.state, self._spare = following, previous
            else:
                self.state = xp.stack([x_next, v_next], axis=2)
            disagreement_next = self._disagreement()
        if self.is_numpy:
            # One scalar for the finiteness check (a sum overflowing past 1.8e308 is refused too:
            # such energies would overflow the episode's totals).
            if not math.isfinite(disagreement_next.sum() + energy.sum()):
                self.state, self._spare = previous, following
                raise self._overflow_error(actions, energy, disagreement_next)
        else:
            finite = xp.isfinite(disagreement_next) & xp.all(xp.isfinite(energy), axis=-1)
            self.invalid = self.invalid | ~finite
            if not lock_step:  # in lock step a step past T_s was refused above, on the host
                self.invalid = self.invalid | (self.steps >= self.config.schedule.n_intervals)
        if saturated_time is None:
            saturated = self._no_saturation
        else:
            per_agent = xp.mean(saturated_time, axis=-1)
            saturated = per_agent / (T if lock_step else T[..., 0])
            self.saturated_time += per_agent
        if lock_step:
            self.k += 1
            reached = self.k
        else:
            self.steps = xp.minimum(self.steps + 1, xp.full_like(self.steps, self.config.schedule.n_intervals))
            reached = self.steps
        self._tick += 1
        self.current_disagreement = disagreement_next
        log_previous = self._log_disagreement
        self._log_disagreement = xp.log(self.current_disagreement + self.floor)
        reward = log_previous - self._log_disagreement
        self.energy_total += energy
        self.peak_total = xp.maximum(self.peak_total, peak)
        above = self.current_disagreement * self._inverse_d0 >= self._thresholds
        if self.is_numpy and lock_step:
            np.copyto(self.last_above, self.k, where=above)
        else:
            self.last_above = xp.where(above, reached + xp.zeros_like(self.last_above), self.last_above)
        self._draw_graphs()
        terminated = self.done if lock_step else self.episode_done()
        plan = plan if self.config.model is not None else None
        return StepOutcome(reward, energy, peak, u0, u1, saturated, terminated, plan)

    def _steer(self, actions: np.ndarray) -> tuple[np.ndarray, ...]:
        """A general agent's interval: the plan's minimum-energy input (:mod:`fxc_env.core.linear`).

        ``actions`` ``(B, N, n dim)`` are plans ``Delta`` (terminal change relative to free
        motion, component-major like the state), in normalized mode ``alpha`` with
        ``Delta_l = s_i alpha_l / row_scales_l``. Returns the next state ``(B, N, n, dim)``, energy
        and peak ``(B, N)``, and the input at both ends ``(B, N, dim)`` (``(B, N, dim, m)`` for m > 1).
        """
        c = self.config
        b, n_agents, n, dim = self.n_episodes, c.n_agents, c.n_states, c.dim
        plan = actions.reshape(b, n_agents, n, dim)
        if c.obs_mode == "normalized":
            plan = plan * (self.local_scale()[:, :, None, None] / self._row_scales[self.k][:, None])
        maps = c.interval_maps
        per_axis = np.swapaxes(self.state, -1, -2)  # (B, N, dim, n)
        delta = np.swapaxes(plan, -1, -2)
        following, energy, peak = maps.steer(self.k, per_axis, delta)
        # The input at both ends: u(0+) = B^T F^T lambda, u(T-) = B^T lambda.
        costate = maps.costate(self.k, delta)  # (B, N, dim, n)
        model = c.model
        u_end = costate @ model.B
        u_start = costate @ (maps.motion[self.k] @ model.B)
        if model.n_inputs == 1:
            u_start, u_end = u_start[..., 0], u_end[..., 0]
        return np.swapaxes(following, -1, -2), energy.sum(axis=-1), peak.max(axis=-1), u_start, u_end, delta

    def _overflow_error(self, actions: np.ndarray, energy: np.ndarray, disagreement_next: np.ndarray) -> ArgumentError:
        """The error of a step whose result would not be finite in float64, naming what caused it."""
        bad_episodes = np.flatnonzero(~np.isfinite(disagreement_next) | ~np.isfinite(energy).all(axis=-1))
        b = int(bad_episodes[0])
        agents = np.flatnonzero(~np.isfinite(energy[b]) | ~np.isfinite(self._spare[b]).all(axis=(-2, -1)))
        shown = [int(a) for a in agents[:10]]
        episode = f" in episode {b}" if self.n_episodes > 1 else ""
        largest = float(np.max(np.abs(actions[b])))
        return ArgumentError(
            f"actions: the interval k = {self.k} (T = {self.current_interval():g} s) would overflow float64{episode} "
            f"(agents {shown}: a non-finite state, energy or disagreement); the largest action entry is {largest:g}. "
            "The step was refused and the state is unchanged; smaller actions (or a smaller obs_noise / state "
            "scale) keep it finite"
        )

    def _disagreement(self) -> Any:
        """``D = e_x + T_s e_v`` per episode; for ``dim = 1`` from one max and one min over agents."""
        xp = self.xp
        if self.config.model is not None:
            return state_disagreement(self.state, self.config)
        if self.config.dim == 1:
            values = self.state[..., 0]  # (B, N, 2)
            if self.is_numpy:
                if values.size > slots.SMALL:
                    # numpy fast path: reducing over a middle axis is slow in numpy (10x at
                    # N = 1e6); agents last is not.
                    values = np.ascontiguousarray(np.swapaxes(values, 1, 2))  # (B, 2, N)
                    ranges = values.max(axis=-1) - values.min(axis=-1)
                else:
                    ranges = values.max(axis=1) - values.min(axis=1)
                return ranges @ self._range_weights  # e_x + T_s e_v
            ranges = xp.max(values, axis=1) - xp.min(values, axis=1)
            return ranges[:, 0] + self.config.settling_time * ranges[:, 1]
        return disagreement(self.x, self.v, self.config.settling_time)

    # ---------------------------------------------------------------- metrics
    def batch_metrics(self) -> dict[str, np.ndarray]:
        """The metrics (README, "Baselines and the deadline benchmark") of every episode so far, one ``(B,)`` numpy array per :class:`EpisodeMetrics` field.

        Final values are those at each episode's current instant. On torch this reads the
        state off the device (call it at the end of an episode, not on the stepping path).
        """
        c = self.config
        x, v = to_host(self.x), to_host(self.v)
        steps = np.full(self.n_episodes, self.k) if self.steps is None else to_host(self.steps)
        times = np.concatenate([c.schedule.times, [np.inf]])
        t_eps = times[to_host(self.last_above) + 1]  # (thresholds, B)
        # xi (dense, so only for moderate N) is computed on first use, never on the stepping path.
        if c.n_agents <= DENSE_LIMIT and c.switching == "periodic":
            # xi of the shared topology (N,), or of each episode's own (B, N).
            xi = (
                self.topologies[0].consensus_weights()
                if self._shared_topology
                else np.stack([topology.consensus_weights() for topology in self.topologies])
            )
            # Theorems 1-2 (generalised): z*(T_s) = e^{A T_s} sum_j xi_j z_j(0), in the engine's coordinates.
            z0 = to_host(self.z0)[:, :, :, 0]  # (B, N, n), first axis
            weighted = np.stack([_weighted_sum(z0[:, :, component], xi) for component in range(c.n_states)], axis=-1)
            if c.model is None:
                predicted_v = weighted[:, 1]
                predicted_x = weighted[:, 0] + c.settling_time * predicted_v
            else:
                final = weighted @ c.model.free_motion_matrix(c.settling_time).T
                predicted_x = final[:, 0]
                predicted_v = final[:, 1] if c.n_states > 1 else np.zeros(self.n_episodes)
        else:
            predicted_x = predicted_v = np.full(self.n_episodes, np.nan)
        elapsed = np.maximum(c.schedule.times[steps], TINY)
        return {
            "final_position_spread": spread(x),
            "final_velocity_spread": spread(v),
            "relative_deadline_error": to_host(self.current_disagreement * self._inverse_d0),
            "t_eps_1e_2": t_eps[0],
            "t_eps_1e_6": t_eps[1],
            "energy": to_host(self.energy_total).sum(axis=1),
            "peak_input": to_host(self.peak_total).max(axis=1, initial=0.0),
            "sampling_instants": steps.astype(np.int64),
            "predicted_final_position": predicted_x,
            "achieved_final_position": x[:, :, 0].mean(axis=1),
            "predicted_final_velocity": predicted_v,
            "achieved_final_velocity": v[:, :, 0].mean(axis=1),
            "saturated_fraction": to_host(self.saturated_time).mean(axis=1) / elapsed,
        }

    def episode_metrics(self, episode: int = 0) -> EpisodeMetrics:
        """The metrics of one episode so far (see :meth:`batch_metrics`)."""
        return EpisodeMetrics(**{name: column[episode].item() for name, column in self.batch_metrics().items()})
