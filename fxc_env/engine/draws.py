"""What a new episode draws at reset: its initial state, and where the config asks, its topology and input limit.

Two ways to draw, with the same distributions:

- :func:`draw_episode`: one episode from its own seeded numpy generator (the PettingZoo env,
  the VecEnv, :func:`fxc_env.simulate`), in a fixed order so that seeds keep their episodes;
- :func:`draw_batch`: every episode at once on the engine's device (the TorchRL env).

Positions are drawn from ``U(-a, a)`` and velocities from ``U(-b, b)`` per component with
``a = position_range`` and ``b = velocity_range`` (defaults 5 m and 2 m/s); a ``(low, high)``
range first draws the half-width log-uniformly, so episodes span decades of scale.
:func:`stack_draws` turns per-episode draws into the arguments of one batched
:meth:`~fxc_env.engine.ConsensusEngine.reset` (see :meth:`~fxc_env.engine.ConsensusEngine.reset_from_draws`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core.graphs import Topology
from fxc_env.core.validation import ArgumentTypeError


@dataclass(frozen=True)
class EpisodeDraw:
    """What one episode drew at reset: its initial state ``(N, dim)`` each, and, where the
    config asks for a draw, its topology (a family) and its input limit (a set of ``u_max``)."""

    x0: np.ndarray
    v0: np.ndarray
    topology: Topology | None = None
    u_max: float | None = None


@dataclass(frozen=True)
class BatchDraw:
    """Every episode's draw stacked: ``x0, v0`` ``(B, N, dim)``, a topology per episode (None:
    the config's) and a limit per episode (None without a set of limits)."""

    x0: Any
    v0: Any
    topologies: list[Topology | None] | None
    u_max: Any


def _draw_scale(half_widths: tuple[float, float], rng: np.random.Generator) -> float:
    """``low`` when the range is one number, else a log-uniform draw from ``[low, high]``."""
    low, high = half_widths
    return low if low == high else float(np.exp(rng.uniform(np.log(low), np.log(high))))


def sample_initial_state(config: EnvConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One episode's ``(x0, v0)``, ``(N, dim)`` numpy each: the config's initial state, else uniform draws."""
    if config.initial_state is not None:
        return config.initial_state[0].copy(), config.initial_state[1].copy()
    shape = (config.n_agents, config.dim)
    position_range = _draw_scale(config.position_range, rng)
    velocity_range = _draw_scale(config.velocity_range, rng)
    x0 = rng.uniform(-position_range, position_range, size=shape)
    return x0, rng.uniform(-velocity_range, velocity_range, size=shape)


def draw_episode(config: EnvConfig, rng: np.random.Generator) -> EpisodeDraw:
    """One episode's draw from its seeded numpy generator, in this order.

    Its topology when the config has a family, its input limit when ``u_max`` is a set,
    then ``(x0, v0)`` (:func:`sample_initial_state`). A config with none of these draws
    exactly what it always did, so seeds keep their episodes. ``rng`` other than a numpy
    ``Generator`` raises :class:`~fxc_env.core.validation.ArgumentTypeError` naming it.
    """
    if not isinstance(rng, np.random.Generator):
        raise ArgumentTypeError(f"rng: expected a numpy Generator (np.random.default_rng), got {type(rng).__name__}")
    topology = None if config.family is None else config.family.draw(config.n_agents, rng)
    choices = config.u_max_choices
    u_max = None if choices is None else choices[0] if len(choices) == 1 else float(rng.choice(choices))
    x0, v0 = sample_initial_state(config, rng)
    return EpisodeDraw(x0, v0, topology, u_max)


def with_initial_state(draw: EpisodeDraw, x0: np.ndarray | None, v0: np.ndarray | None) -> EpisodeDraw:
    """``draw`` with a user's (already validated) initial positions and/or velocities in place of the drawn ones."""
    return replace(draw, x0=draw.x0 if x0 is None else x0, v0=draw.v0 if v0 is None else v0)


def stack_draws(draws: Sequence[EpisodeDraw], config: EnvConfig) -> BatchDraw:
    """Per-episode draws as one batch: ``x0, v0`` stacked ``(B, N, dim)``, topologies and limits listed."""
    topologies = None if config.family is None else [d.topology for d in draws]
    u_max = None if config.u_max_choices is None else [d.u_max for d in draws]
    return BatchDraw(np.stack([d.x0 for d in draws]), np.stack([d.v0 for d in draws]), topologies, u_max)


def draw_batch(
    config: EnvConfig,
    backend: Any,
    uniform: Callable[[tuple[int, ...]], Any],
    host_rng: np.random.Generator | None = None,
) -> BatchDraw:
    """Every episode's draw at once, on the device, from ``uniform`` (the engine's generator).

    The same distributions as :func:`draw_episode` (the half-widths log-uniform when given
    as ranges, then uniform states; ``u_max`` uniform over the set), ``(B, N, dim)`` each and
    ``(B,)`` (None without a limit). A topology family is the one draw made on the host
    (``host_rng``; graphs are built and checked there, once per episode, never per step).
    """
    xp, b = backend.xp, backend.n_episodes
    shape = (b, config.n_agents, config.dim)
    if config.initial_state is not None:
        x0 = backend.array(np.broadcast_to(config.initial_state[0], shape))
        v0 = backend.array(np.broadcast_to(config.initial_state[1], shape))
    else:
        x0 = (2.0 * uniform(shape) - 1.0) * _half_widths(config.position_range, xp, uniform, b)
        v0 = (2.0 * uniform(shape) - 1.0) * _half_widths(config.velocity_range, xp, uniform, b)
    u_max = None
    if config.u_max_choices is not None:
        choices = backend.array(config.u_max_choices)
        pick = xp.astype(xp.floor(uniform((b,)) * len(config.u_max_choices)), xp.int64)
        u_max = xp.take(choices, xp.clip(pick, 0, len(config.u_max_choices) - 1), axis=0)
    topologies = None
    if config.family is not None:
        rng = np.random.default_rng() if host_rng is None else host_rng
        topologies = [config.family.draw(config.n_agents, rng) for _ in range(b)]
    return BatchDraw(x0, v0, topologies, u_max)


def switching_draw(backend: Any, rng: Any, shared: bool, periods: Any) -> Any:
    """Random switching: each episode's graph index on the coming interval, uniform in ``[0, m_b)``, ``(B,)`` int64.

    ``periods`` ``(B,)``: each episode's number of graphs ``m_b``; ``rng``: the engine's generator.
    numpy with one topology for every episode (``shared``) draws integers; otherwise
    ``floor(u m_b)`` of uniform draws on the device.
    """
    if backend.is_numpy and shared:
        return rng.integers(0, int(periods[0]), backend.n_episodes)
    xp = backend.xp
    local = xp.floor(backend.uniform(rng, (backend.n_episodes,)) * xp.astype(periods, backend.dtype))
    return xp.astype(local, xp.int64)


def _half_widths(half_widths: tuple[float, float], xp: Any, uniform: Callable, b: int) -> Any:
    """``(B, 1, 1)`` half-widths: the number, or log-uniform draws from ``[low, high]``."""
    low, high = half_widths
    if low == high:
        return low
    return xp.exp(math.log(low) + uniform((b, 1, 1)) * (math.log(high) - math.log(low)))
