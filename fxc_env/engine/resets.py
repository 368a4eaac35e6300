"""What a reset takes besides the initial states, checked before anything changes, and what it sets from them.

:meth:`ConsensusEngine.reset <fxc_env.engine.ConsensusEngine.reset>` restarts every episode, or
only those of a boolean mask (TorchRL's partial reset), from ``x0, v0`` and, optionally, a new
generator of noise, dropout and switching, one topology per episode and one input limit per
episode. :func:`checked_reset` refuses, naming it, any of these (or a state) that does not fit,
before the engine changes; :func:`episode_topologies` and :func:`episode_limits` then give the graphs'
topologies and the limits the episodes play with (those that go on keep theirs).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core import validation
from fxc_env.core.graphs import Topology
from fxc_env.core.validation import ArgumentError, ArgumentTypeError

from .clock import EpisodeClock, InstantTables, LockStepClock


def checked_reset(
    config: EnvConfig,
    backend: Any,
    current_limits: Any,
    x0: Any,
    v0: Any,
    rng: Any,
    topologies: Any,
    u_max: Any,
    episodes: Any,
) -> tuple[Any, Any]:
    """``x0, v0`` ``(B, N, dim)`` as the back end holds them, every reset argument checked (before anything changes).

    The states first, on both back ends by the same check (shape, real, finite, within
    ``config.state_limit``; a torch tensor's values in one read off the device), then the
    others (:func:`check_reset_extras`); the first that does not fit raises naming it.
    """
    shape, limit = (backend.n_episodes, config.n_agents, config.dim), config.state_limit
    x0, v0 = backend.checked_state("x0", x0, shape, limit), backend.checked_state("v0", v0, shape, limit)
    backend.check_state_values({"x0": x0, "v0": v0}, limit)
    check_reset_extras(config, backend, current_limits, rng, topologies, u_max, episodes)
    return x0, v0


def check_reset_extras(
    config: EnvConfig, backend: Any, current_limits: Any, rng: Any, topologies: Any, u_max: Any, episodes: Any
) -> None:
    """Refuse, naming it, a reset argument beside the states that does not fit (before anything changes).

    ``rng``: a numpy ``Generator`` (numpy back end) or a ``torch.Generator`` (torch);
    ``topologies``: one :class:`~fxc_env.core.graphs.Topology` of N agents (or None) per episode;
    ``u_max``: one positive limit within ±1e100 (m/s^2) per episode, only where the config has a
    limit (``current_limits`` is not None); ``episodes``: a ``(B,)`` boolean array of the back end.
    """
    b = backend.n_episodes
    if episodes is not None and config.model is not None:
        raise ArgumentError(
            f"episodes: partial resets are for the double integrator, not {config.agent_model!r} agents"
        )
    if rng is not None:
        _check_generator(rng, backend.is_numpy)
    if topologies is not None:
        if isinstance(topologies, str | bytes) or not isinstance(topologies, Sequence) or len(topologies) != b:
            raise ArgumentError(f"topologies: expected one topology (or None) per episode, {b} in all")
        for topology in topologies:
            if topology is not None and (not isinstance(topology, Topology) or topology.n_agents != config.n_agents):
                raise ArgumentError(
                    f"topologies: expected Topology objects of {config.n_agents} agents (or None), got {topology!r:.80}"
                )
    if u_max is not None:
        if current_limits is None:
            raise ArgumentError("u_max: this engine's config has no input limit (give u_max to make_config)")
        _check_limits(config, backend, u_max)
    if episodes is not None:
        dtype = getattr(episodes, "dtype", None)
        if tuple(getattr(episodes, "shape", ())) != (b,) or dtype not in (np.bool_, backend.xp.bool):
            raise ArgumentError(
                f"episodes: expected a boolean array of shape ({b},) on the engine's device, got {episodes!r:.80}"
            )


def _check_generator(rng: Any, is_numpy: bool) -> None:
    """Refuse an ``rng`` that is not the back end's generator."""
    if is_numpy:
        fits, expected = isinstance(rng, np.random.Generator), "a numpy Generator (np.random.default_rng)"
    else:
        import torch

        fits, expected = isinstance(rng, torch.Generator), "a torch.Generator"
    if not fits:
        raise ArgumentTypeError(f"rng: expected None or {expected}, got {type(rng).__name__}")


def _check_limits(config: EnvConfig, backend: Any, u_max: Any) -> None:
    """Refuse ``u_max`` unless it is one positive finite limit per episode (host values checked in full)."""
    b = backend.n_episodes
    if backend.is_numpy or isinstance(u_max, np.ndarray | list | tuple):
        array = validation.real_array("u_max", _with_default_limits(config, u_max), f"an array of shape ({b},)")
        if array.shape != (b,):
            raise ArgumentError(f"u_max: expected one limit per episode, shape ({b},), got {array.shape}")
        if not np.all((array > 0) & (array <= validation.STATE_LIMIT)):
            raise ArgumentError(
                f"u_max: expected positive finite limits <= {validation.STATE_LIMIT:g} (m/s^2), one per episode"
            )
    elif tuple(u_max.shape) != (b,):
        raise ArgumentError(f"u_max: expected one limit per episode, shape ({b},), got {tuple(u_max.shape)}")


def _with_default_limits(config: EnvConfig, u_max: Any) -> Any:
    """A list or tuple of limits with each None read as the config's first limit; anything else as given."""
    if isinstance(u_max, list | tuple):
        return [config.u_max_choices[0] if u is None else u for u in u_max]
    return u_max


def episode_topologies(config: EnvConfig, topologies: Sequence[Topology | None]) -> list[Topology]:
    """One topology per episode: the one given, or the config's where None is given."""
    return [config.topology if t is None else t for t in topologies]


def episode_limits(config: EnvConfig, backend: Any, u_max: Any, episodes: Any, current_limits: Any) -> Any:
    """The limits ``(B,)`` after a reset with checked ``u_max``: the given ones, or only the ``episodes``' rows."""
    if isinstance(u_max, Sequence) and not hasattr(u_max, "shape"):
        u_max = _with_default_limits(config, u_max)
    given = backend.array(u_max) if backend.is_numpy or isinstance(u_max, np.ndarray | list) else u_max
    return given if episodes is None else backend.xp.where(episodes, given, current_limits)


def restarted(
    backend: Any, tables: InstantTables, state: Any, clock: Any, fresh: Any, episodes: Any
) -> tuple[Any, Any]:
    """The state ``(B, N, n, dim)`` and clock after a reset to ``fresh`` of every episode, or of ``episodes`` only.

    A full reset starts the lock-step clock at ``t_0``; numpy writes into ``state`` (the double
    buffer keeps its two arrays), torch takes the new tensor (nothing of the previous episodes'
    autograd graph is kept). A partial reset keeps the other episodes' rows and steps, each
    episode on its own clock from then on.
    """
    xp = backend.xp
    if episodes is None:
        if backend.is_numpy:
            state[...] = fresh
        else:
            state = fresh
        return state, LockStepClock(tables)
    state = xp.where(xp.reshape(episodes, (-1, 1, 1, 1)), fresh, state)
    current = clock.episode_steps(backend)
    return state, EpisodeClock(tables, xp.where(episodes, xp.zeros_like(current), current), clock.k)
