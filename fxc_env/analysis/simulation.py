"""Run a policy through one episode and keep the whole trajectory (for plots and tests)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig, make_config
from fxc_env.core.dynamics import advance_clipped, state_inside
from fxc_env.core.graphs import Topology
from fxc_env.core.metrics import EpisodeMetrics
from fxc_env.core.validation import ArgumentError, integer, optional_seed
from fxc_env.engine import ConsensusEngine, state_disagreement, with_initial_state
from fxc_env.policies.reference import ReferencePolicy

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One episode, sampled and dense. Seconds, metres, m/s, m/s^2.

    Attributes:
        times: ``(K + 1,)`` sampling instants ``t_0 .. t_K`` (``t_K = T_s``).
        x, v: ``(K + 1, N, dim)`` positions and velocities at the sampling instants (absolute:
            with formation offsets they include ``e^{A t} h``; zero velocities for a single integrator).
        u_start, u_end: ``(K, N, dim)`` commanded input at ``t_k+`` and ``t_{k+1}-`` (the
            applied input is this line clipped to ``±u_max`` when the config sets it).
        dense_times: ``(P,)`` time points, ``points_per_interval`` per interval plus ``T_s``.
        dense_x, dense_v, dense_u: ``(P, N, dim)`` exact state and applied input there
            (``dense_u`` at ``T_s`` repeats the last interval's end value).
        disagreement: ``(K + 1,)`` ``D(t_k)`` (of the formation error with offsets); ``dense_disagreement`` ``(P,)``.
        metrics: the episode's figures (docs: environment.md, "The environment").
        config: the settings the episode ran with.
        topology: the episode's graphs (the config's, or its family's draw).
        u_max: the episode's input limit (m/s^2; drawn when the config gives a set), or None.
        states: ``(K + 1, N, n, dim)`` the full states at the sampling instants in the engine's
            coordinates (the formation error with offsets), or None.
        plans: ``(K, N, dim, n)`` each interval's minimum-energy plan of a general agent (its
            ``z(t_{k+1}) - F_k z(t_k)``), or None (the double integrator's input is ``u_start``/``u_end``).
        graphs: ``(K,)`` the index in ``topology.edges`` of each interval's graph, or None.
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
    states: np.ndarray | None = None
    plans: np.ndarray | None = None
    graphs: np.ndarray | None = None


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
    draw = with_initial_state(
        draw,
        None if x0 is None else engine.validate_state("x0", x0),
        None if v0 is None else engine.validate_state("v0", v0),
    )
    act = ReferencePolicy(config) if isinstance(policy, str) and policy == "reference" else policy
    if isinstance(act, str) or not callable(act):
        raise ArgumentError(f"policy: expected 'reference' or a callable, got {policy!r}")
    engine.reset_from_draws([draw], rng=rng)
    u_max = None if engine.u_max is None else float(engine.u_max[0])
    states, u_start, u_end, plans, graphs = _play(engine, act)
    return _trajectory(config, engine, states, u_start, u_end, plans, graphs, points_per_interval, u_max)


def _play(engine: ConsensusEngine, act: Any) -> tuple[list, list, list, list, list]:
    """One episode of ``act``: the states after every step (the first before), inputs, plans and graphs."""
    states = [engine.state[0].copy()]  # (N, n, dim) in the engine's coordinates (formation error)
    u_start, u_end, plans, graphs = [], [], [], []
    while not engine.done:
        graphs.append(int(engine.graph_indices()[0]))
        if isinstance(act, ReferencePolicy):  # its plan from the neighbour sums where observations are exact
            outcome = act.step(engine)
        else:
            outcome = engine.step(engine.validate_actions(act(engine.observations()), name="policy output"))
        states.append(engine.state[0].copy())
        u_start.append(outcome.u_start[0])
        u_end.append(outcome.u_end[0])
        if outcome.plan is not None:
            plans.append(outcome.plan[0])
    return states, u_start, u_end, plans, graphs


def _trajectory(config, engine, states, u_start, u_end, plans, graphs, points_per_interval, u_max) -> Trajectory:
    """The episode's :class:`Trajectory`, dense in time in closed form."""
    z = np.array(states)  # (K + 1, N, n, dim)
    u0, u1 = np.array(u_start), np.array(u_end)
    times, intervals = config.schedule.times, config.schedule.intervals
    offsets = intervals[:, None] * (np.arange(points_per_interval) / points_per_interval)  # (K, P)
    dense_times = np.concatenate([(times[:-1, None] + offsets).ravel(), times[-1:]])
    if config.model is None:
        dense_z, dense_u = _dense_double_integrator(z, u0, u1, intervals, offsets, u_max)
    else:
        dense_z, dense_u = _dense_linear(config, z, np.array(plans), offsets, u1)
    disagreement_sampled = state_disagreement(z, config)
    disagreement_dense = state_disagreement(dense_z, config)
    if config.formation is not None:  # absolute states: the formation error plus e^{A t} h
        z = z + config.formation_motion[:, None] @ config.formation
        dense_z = dense_z + config.free_motion(dense_times)[:, None] @ config.formation
    x, dense_x = z[:, :, 0], dense_z[:, :, 0]
    v, dense_v = (z[:, :, 1], dense_z[:, :, 1]) if config.n_states > 1 else (np.zeros_like(x), np.zeros_like(dense_x))
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
        disagreement=disagreement_sampled,
        dense_disagreement=disagreement_dense,
        metrics=engine.episode_metrics(0),
        config=config,
        topology=engine.topologies[0],
        u_max=u_max,
        states=np.array(states),
        plans=np.array(plans) if plans else None,
        graphs=np.array(graphs),
    )


def _dense_double_integrator(z, u0, u1, intervals, offsets, u_max):
    """Dense states ``(P, N, 2, dim)`` and inputs ``(P, N, dim)`` inside every interval, closed form."""
    x, v = z[:, :, 0], z[:, :, 1]
    k_total, points = offsets.shape
    s = offsets[:, :, None, None]
    pick = lambda a: a[:, None]  # noqa: E731  (K, ...) -> (K, 1, ...) against s (K, P, 1, 1)
    T = intervals[:, None, None, None]
    dx, dv, du = state_inside(pick(x[:-1]), pick(v[:-1]), pick(u0), pick(u1), T, s)
    if u_max is not None:
        # The clipped input on [0, s] is the line from u0 to u(s), clipped: integrate that.
        reach = np.maximum(s, np.finfo(float).tiny)
        dx, dv, *_ = advance_clipped(pick(x[:-1]), pick(v[:-1]), pick(u0), du, reach, u_max)
        du = np.clip(du, -u_max, u_max)
    flat = (k_total * points, *x.shape[1:])
    dense_x = np.concatenate([dx.reshape(flat), x[-1:]])
    dense_v = np.concatenate([dv.reshape(flat), v[-1:]])
    last_u = u1[-1:] if u_max is None else np.clip(u1[-1:], -u_max, u_max)
    dense_u = np.concatenate([du.reshape(flat), last_u])
    return np.stack([dense_x, dense_v], axis=2), dense_u


def _dense_linear(config: EnvConfig, z, plans, offsets, u_end):
    """Dense states ``(P, N, n, dim)`` and inputs ``(P, N, dim)`` (first input) of a general agent.

    Each interval's state and minimum-energy input at the offsets, from matrix exponentials
    (:meth:`fxc_env.core.linear.IntervalMaps.state_inside`), never from an ODE solver.
    """
    maps = config.interval_maps
    states, inputs = [], []
    for k in range(offsets.shape[0]):
        per_axis = np.swapaxes(z[k], -1, -2)  # (N, dim, n)
        inside, u = maps.state_inside(k, per_axis, plans[k], np.minimum(offsets[k], maps.intervals[k]))
        states.append(np.swapaxes(inside, -1, -2))  # (P, N, n, dim)
        inputs.append(u[..., 0])  # (P, N, dim)
    last_u = u_end[-1:] if u_end.ndim == 3 else u_end[-1:, ..., 0]
    return np.concatenate([*states, z[-1:]]), np.concatenate([*inputs, last_u])
