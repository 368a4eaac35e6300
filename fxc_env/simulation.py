"""Run a policy through one episode and keep the whole trajectory (for plots and tests)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig, make_config
from fxc_env.core.dynamics import advance_clipped, state_inside
from fxc_env.core.graphs import Topology
from fxc_env.core.metrics import EpisodeMetrics, disagreement
from fxc_env.core.validation import ArgumentError, integer, optional_seed
from fxc_env.engine import ConsensusEngine
from fxc_env.reference import ReferencePolicy

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One episode, sampled and dense. Seconds, metres, m/s, m/s^2.

    Attributes:
        times: ``(K + 1,)`` sampling instants ``t_0 .. t_K`` (``t_K = T_s``).
        x, v: ``(K + 1, N, dim)`` states at the sampling instants.
        u_start, u_end: ``(K, N, dim)`` commanded input at ``t_k+`` and ``t_{k+1}-`` (the
            applied input is this line clipped to ``±u_max`` when the config sets it).
        dense_times: ``(P,)`` time points, ``points_per_interval`` per interval plus ``T_s``.
        dense_x, dense_v, dense_u: ``(P, N, dim)`` exact state and applied input there
            (``dense_u`` at ``T_s`` repeats the last interval's end value).
        disagreement: ``(K + 1,)`` ``D(t_k)``; ``dense_disagreement`` ``(P,)``.
        metrics: the episode's figures (README, "Metrics").
        config: the settings the episode ran with.
        topology: the episode's graphs (the config's, or its family's draw).
        u_max: the episode's input limit (m/s^2; drawn when the config gives a set), or None.
    """

    times: np.ndarray
    x: np.ndarray
    v: np.ndarray
    u_start: np.ndarray
    u_end: np.ndarray
    dense_times: np.ndarray
    dense_x: np.ndarray
    dense_v: np.ndarray
    dense_u: np.ndarray
    disagreement: np.ndarray
    dense_disagreement: np.ndarray
    metrics: EpisodeMetrics
    config: EnvConfig
    topology: Topology
    u_max: float | None


def simulate(
    policy: Policy | str = "reference",
    scenario: str | None = "paper_fig1",
    *,
    seed: int | None = 0,
    x0: Any = None,
    v0: Any = None,
    points_per_interval: int = 24,
    **env_kwargs: Any,
) -> Trajectory:
    """Run ``policy`` for one episode of ``scenario`` (with ``env_kwargs`` overriding it).

    Args:
        policy: ``"reference"`` (eq. 11) or a callable mapping observations
            ``(1, N, obs_size)`` to actions ``(1, N, 2 dim)``; it sees nothing else.
        scenario: a name from :data:`fxc_env.SCENARIOS`, or None for the environment's defaults.
        seed: seeds the episode: the random initial state (when the scenario has none), then
            measurement noise, link dropout and random switching from the same generator, so
            the episode equals ``ConsensusParallelEnv.reset(seed=seed)`` driven by the same
            policy. None draws fresh entropy.
        x0, v0: explicit initial state ``(N, dim)`` (``(N,)`` when ``dim = 1``).
        points_per_interval: dense samples per interval for smooth curves.
        env_kwargs: any keyword argument of :func:`fxc_env.make_config`.
    """
    config = make_config(scenario, **env_kwargs)
    seed = optional_seed("seed", seed)
    points_per_interval = integer("points_per_interval", points_per_interval, 1)
    engine = ConsensusEngine(config, n_episodes=1)
    # One stream per episode, as ConsensusParallelEnv.reset(seed=seed): the initial state first,
    # then measurement noise, link dropout and random switching go on from it.
    rng = np.random.default_rng(seed)
    draw = engine.draw_episode(rng)
    x_start = draw.x0 if x0 is None else engine.validate_state("x0", x0)
    v_start = draw.v0 if v0 is None else engine.validate_state("v0", v0)
    act = ReferencePolicy(config) if isinstance(policy, str) and policy == "reference" else policy
    if isinstance(act, str):
        raise ArgumentError(f"policy: expected 'reference' or a callable, got {policy!r}")
    engine.reset(x_start[None], v_start[None], rng=rng, topologies=[draw.topology], u_max=[draw.u_max])
    u_max = None if engine.u_max is None else float(engine.u_max[0])
    k_total = config.n_intervals
    xs, vs = [engine.x[0].copy()], [engine.v[0].copy()]
    u_start, u_end = [], []
    while not engine.done:
        actions = engine.validate_actions(act(engine.observations()), name="policy output")
        outcome = engine.step(actions)
        xs.append(engine.x[0].copy())
        vs.append(engine.v[0].copy())
        u_start.append(outcome.u_start[0])
        u_end.append(outcome.u_end[0])
    x, v = np.array(xs), np.array(vs)
    u0, u1 = np.array(u_start), np.array(u_end)
    times, intervals = config.schedule.times, config.schedule.intervals
    offsets = intervals[:, None] * (np.arange(points_per_interval) / points_per_interval)  # (K, P)
    s = offsets[:, :, None, None]
    pick = lambda a: a[:, None]  # noqa: E731  (K, ...) -> (K, 1, ...) against s (K, P, 1, 1)
    T = intervals[:, None, None, None]
    dx, dv, du = state_inside(pick(x[:-1]), pick(v[:-1]), pick(u0), pick(u1), T, s)
    if u_max is not None:
        # The clipped input on [0, s] is the line from u0 to u(s), clipped: integrate that.
        reach = np.maximum(s, np.finfo(float).tiny)
        dx, dv, *_ = advance_clipped(pick(x[:-1]), pick(v[:-1]), pick(u0), du, reach, u_max)
        du = np.clip(du, -u_max, u_max)
    flat = (k_total * points_per_interval, *x.shape[1:])
    dense_times = np.concatenate([(times[:-1, None] + offsets).ravel(), times[-1:]])
    dense_x = np.concatenate([dx.reshape(flat), x[-1:]])
    dense_v = np.concatenate([dv.reshape(flat), v[-1:]])
    last_u = u1[-1:] if u_max is None else np.clip(u1[-1:], -u_max, u_max)
    dense_u = np.concatenate([du.reshape(flat), last_u])
    return Trajectory(
        times=times,
        x=x,
        v=v,
        u_start=u0,
        u_end=u1,
        dense_times=dense_times,
        dense_x=dense_x,
        dense_v=dense_v,
        dense_u=dense_u,
        disagreement=disagreement(x, v, config.settling_time),
        dense_disagreement=disagreement(dense_x, dense_v, config.settling_time),
        metrics=engine.episode_metrics(0),
        config=config,
        topology=engine.topologies[0],
        u_max=u_max,
    )
