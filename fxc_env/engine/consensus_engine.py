"""The batched consensus engine: B independent episodes of N double-integrator agents.

This is the one code path behind every front end: the PettingZoo environment is the
``n_episodes = 1`` case, the SB3 VecEnv and :func:`fxc_env.simulate` use larger batches,
and the TorchRL environment (:mod:`fxc_env.envs.torch_env`) runs it on torch tensors. Arrays
are numpy arrays (``device=None``, the default) or torch tensors on ``device`` (``"cpu"``,
``"cuda"``, ``"meta"``), float64 by default: the state is ``(B, N, n, dim)`` (component major,
space axis last: ``state[:, :, 0]`` positions ``x``, ``state[:, :, 1]`` velocities ``v``);
observations ``(B, N, obs_size)``; actions ``(B, N, 2 dim)``.

One step integrates the affine input on ``[t_k, t_{k+1})`` in closed form
(:mod:`fxc_env.core.dynamics`), clipped to ``±u_max`` when that is set; noise, dropout and
random switching draw from :attr:`ConsensusEngine.rng`. The engine wires named parts (backend,
clock, graph table, draws, agents, observations, trackers), each choosing its branch once, at
construction (docs: architecture.md, "Layers"). On numpy a step whose result would not be finite
is refused at once, state unchanged; on torch it sets a per-episode flag, read off the hot path by
:meth:`ConsensusEngine.raise_if_invalid`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fxc_env.config import EnvConfig
from fxc_env.core import validation
from fxc_env.core.graphs import Topology
from fxc_env.core.metrics import EpisodeMetrics
from fxc_env.core.validation import ArgumentTypeError

from . import draws, resets
from .agents import Formation, StepOutcome, make_agents, state_disagreement
from .backend import DTYPES, TINY, make_backend, to_host
from .clock import BeforeReset, EpisodeClock, InstantTables, LockStepClock
from .draws import EpisodeDraw
from .graph_table import GraphTable
from .observations import Observer, limit_feature, normalized_state
from .reference import NeighbourPlans
from .trackers import EpisodeTrackers

__all__ = [
    "DTYPES",
    "TINY",
    "ConsensusEngine",
    "EpisodeDraw",
    "StepOutcome",
    "limit_feature",
    "state_disagreement",
    "to_host",
]


def _checked_config(config: object) -> EnvConfig:
    """``config`` if it is an :class:`EnvConfig` (one way in: the settings make_config validated); else raise naming it."""
    if not isinstance(config, EnvConfig):
        shown = f"the name {config!r}" if isinstance(config, str) else f"a {type(config).__name__}"
        hint = f"make_config({config!r})" if isinstance(config, str) else "make_config(...)"
        raise ArgumentTypeError(f"config: expected an EnvConfig ({hint}), got {shown}")
    return config


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
        self.config = _checked_config(config)
        self.n_episodes = b = validation.integer("n_episodes", n_episodes, 1, validation.MAX_AGENTS)
        self.layout = config.layout
        self.backend = backend = make_backend(device, dtype, b)
        shape = (b, config.n_agents, config.n_states, config.dim)
        #: ``(B, N, n, dim)`` at ``t_k``; numpy plays each interval into the spare buffer (double buffering).
        self.state = backend.zeros(shape)
        self._spare = backend.spare(shape)
        self.tables = InstantTables(config, backend)
        self.clock: LockStepClock | EpisodeClock = BeforeReset(self.tables)
        self.graphs = GraphTable([config.topology] * b, self.layout.slots, backend, config.switching == "random")
        self.agents = make_agents(config, backend)
        self.formation = Formation(config, backend)
        self.trackers = EpisodeTrackers(config, backend)
        self.observer = Observer(config, backend, self.tables)
        self.neighbour_plans = NeighbourPlans(config, backend)
        #: Generator of measurement noise, link dropout and random switching.
        self.rng: Any = backend.generator(None)
        self._restart(self.trackers.x0, self.trackers.v0, self.state)

    # ---------------------------------------------------------------- the parts' figures, by their old names
    device = property(lambda self: self.backend.device, doc="The torch device, or None on numpy.")
    xp = property(lambda self: self.backend.xp, doc="The array API namespace of the backend.")
    dtype = property(lambda self: self.backend.dtype, doc="The dtype of every float array.")
    is_numpy = property(lambda self: self.backend.is_numpy, doc="numpy arrays (where the numpy fast paths apply).")
    invalid = property(lambda self: self.backend.invalid, doc="Bad-step flags ``(B,)`` (torch; None on numpy).")
    k = property(lambda self: self.clock.k, doc="Lock-step instant index (host), valid while :attr:`steps` is None.")
    steps = property(
        lambda self: self.clock.steps, doc="Each episode's instant ``(B,)`` after a partial reset, else None."
    )
    time = property(lambda self: self.clock.time, doc="Current sampling instant ``t_k`` in seconds (lock step).")
    topologies = property(lambda self: self.graphs.topologies, doc="Each episode's topology.")
    x0 = property(lambda self: self.trackers.x0, doc="Each episode's initial positions ``(B, N, dim)``.")
    v0 = property(lambda self: self.trackers.v0, doc="Each episode's initial velocities ``(B, N, dim)``.")
    z0 = property(lambda self: self.trackers.z0, doc="Initial states ``(B, N, n, dim)`` (engine coordinates).")
    initial_disagreement = property(lambda self: self.trackers.initial_disagreement, doc="``D(0)`` ``(B,)``.")
    current_disagreement = property(lambda self: self.trackers.current_disagreement, doc="``D(t_k)`` ``(B,)``.")

    u_max = property(
        lambda self: self.agents.u_max,
        lambda self, value: setattr(self.agents, "u_max", value),
        doc="Each episode's input limit ``u_max`` (m/s^2), ``(B,)``, or None without a limit (held by the agents' part).",
    )
    x = property(lambda self: self.state[:, :, 0], doc="Positions ``(B, N, dim)`` at ``t_k``, a view of :attr:`state`.")
    v = property(
        lambda self: self.xp.zeros_like(self.x) if self.config.n_states == 1 else self.state[:, :, 1],
        doc="Velocities ``(B, N, dim)`` at ``t_k`` (a view of :attr:`state`; zeros for a single integrator).",
    )

    done = property(
        lambda self: self.clock.done,
        doc="The deadline has been reached: ``t_k = T_s`` (lock step; see :meth:`episode_done` after a partial reset).",
    )

    def episode_done(self) -> Any:
        """Per episode, whether it reached ``T_s``: ``(B,)`` booleans on the device."""
        return self.clock.episode_steps(self.backend) >= self.config.schedule.n_intervals

    def current_interval(self) -> float:
        """Length ``T = t_{k+1} - t_k`` of the interval about to be played (seconds, lock step)."""
        return self.tables.next_interval[self.clock.k]

    def graph_indices(self) -> Any:
        """Index, within its own topology, of each episode's graph on the current interval, ``(B,)``."""
        return self.graphs.graph_indices()

    # ---------------------------------------------------------------- draws (the one backend-specific piece)
    def seed(self, seed: int | None) -> None:
        """Seed :attr:`rng` (noise, dropout, switching and, on torch, :meth:`draw_batch`).

        ``seed``: None or an integer, in ``[0, 2**128)`` on numpy and ``[0, 2**64)`` on torch
        (a ``torch.Generator``'s range); anything else raises :class:`ArgumentError` naming
        ``seed`` and :attr:`rng` is unchanged.
        """
        self.rng = self.backend.generator(seed)

    def _uniform(self, shape: tuple[int, ...]) -> Any:
        """Uniform draws on ``[0, 1)`` from :attr:`rng`, on the device."""
        return self.backend.uniform(self.rng, shape)

    def _normal(self, shape: tuple[int, ...]) -> Any:
        """Standard normal draws from :attr:`rng`, on the device."""
        return self.backend.normal(self.rng, shape)

    def _switching_draw(self, periods: Any) -> Any:
        """Random switching: each episode's graph index on the coming interval (:func:`~fxc_env.engine.draws.switching_draw`)."""
        return draws.switching_draw(self.backend, self.rng, self.graphs.shared, periods)

    def sample_initial_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One episode's ``(x0, v0)`` (numpy): see :func:`fxc_env.engine.draws.sample_initial_state`."""
        return draws.sample_initial_state(self.config, rng)

    def draw_episode(self, rng: np.random.Generator) -> EpisodeDraw:
        """What a new episode draws from its seeded numpy generator: see :func:`fxc_env.engine.draws.draw_episode`."""
        return draws.draw_episode(self.config, rng)

    def draw_batch(self, host_rng: np.random.Generator | None = None) -> tuple[Any, Any, Any, list | None]:
        """Every episode's draw on the device, from :attr:`rng`: ``(x0, v0, u_max, topologies)`` (:func:`~fxc_env.engine.draws.draw_batch`)."""
        batch = draws.draw_batch(self.config, self.backend, self._uniform, host_rng)
        return batch.x0, batch.v0, batch.u_max, batch.topologies

    def reset_from_draws(self, episode_draws: Sequence[EpisodeDraw], rng: Any = None) -> None:
        """Reset every episode to its :class:`EpisodeDraw` (one per episode, from :meth:`draw_episode`)."""
        batch = draws.stack_draws(episode_draws, self.config)
        self.reset(batch.x0, batch.v0, rng, topologies=batch.topologies, u_max=batch.u_max)

    def validate_state(self, name: str, value: object) -> np.ndarray:
        """A user-given ``(N, dim)`` state array, checked (see :func:`fxc_env.core.validation.state_array`)."""
        return validation.state_array(name, value, self.config.n_agents, self.config.dim, self.config.state_limit)

    # ------------------------------------------------------------------ reset
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

        ``x0`` and ``v0`` are checked before anything changes, on both back ends by the same
        check (:func:`fxc_env.core.validation.state_batch`): shape ``(B, N, dim)``, real, finite,
        within ``±1e100`` (``±1e37`` with raw float32 observations, ``config.state_limit``); a bad
        one raises :class:`ArgumentError` naming it and the engine is unchanged. numpy arrays
        are checked in full; a torch tensor's values in one read off the device (none on ``meta``).
        The other arguments are checked next (:func:`fxc_env.engine.resets.checked_reset`).
        """
        c = self.config
        x0, v0 = resets.checked_reset(c, self.backend, self.u_max, x0, v0, rng, topologies, u_max, episodes)
        if topologies is not None:
            chosen = resets.episode_topologies(c, topologies)
            if any(a is not b for a, b in zip(chosen, self.topologies, strict=True)):
                self.graphs = GraphTable(chosen, self.layout.slots, self.backend, c.switching == "random")
        if u_max is not None and self.u_max is not None:
            self.agents.u_max = resets.episode_limits(c, self.backend, u_max, episodes, self.u_max)
        if rng is not None:
            self.rng = rng
        fresh = self.formation.initial_state(x0, v0)
        self.state, self.clock = resets.restarted(self.backend, self.tables, self.state, self.clock, fresh, episodes)
        self.backend.clear_flags(episodes)
        self._restart(x0, v0, fresh, episodes)

    def _restart(self, x0: Any, v0: Any, fresh: Any, episodes: Any = None) -> None:
        """Restart the trackers of ``episodes`` (None: all), drop the cached measurements, draw the graphs."""
        self.trackers.restart(x0, v0, fresh, self.agents.disagreement(self.state), episodes)
        self.observer.invalidate()
        self.graphs.draw(self.clock, self._switching_draw)

    def absolute_state(self) -> Any:
        """The agents' states ``(B, N, n, dim)`` at ``t_k``: :attr:`state` plus ``e^{A t_k} h`` with formation offsets.

        The engine plays the formation error ``zeta_i = z_i - e^{A t} h_i`` (:class:`~fxc_env.engine.agents.Formation`);
        without offsets this is :attr:`state`.
        """
        return self.formation.absolute(self.state, self.clock)

    # ------------------------------------------------------------ observation
    def measurements(self) -> tuple[Any, Any, Any]:
        """Rows ``(B, N, slots, 2, dim)``, mask and local scale at ``t_k`` (:meth:`Observer.measure <fxc_env.engine.observations.Observer.measure>`)."""
        return self.observer.measure(self.state, self.clock, self.graphs, self._uniform, self._normal)

    def local_scale(self) -> Any:
        """Each agent's local scale ``s_i`` at ``t_k`` (metres), ``(B, N)``; 0 if it sees no disagreement."""
        return self.observer.local_scale(self.state, self.clock, self.graphs, self._uniform, self._normal)

    def observations(self, out: np.ndarray | None = None) -> Any:
        """Every agent's flat observation at ``t_k``, ``(B, N, obs_size)`` (the card's Observation Space).

        ``out`` (optional, numpy, ``(B, N, obs_size)`` float64) is filled instead of a fresh
        array: for loops that consume observations at once, it saves the page faults of
        a new large buffer every step.
        """
        return self.observer.observe(self.state, self.clock, self.graphs, self.u_max, self._uniform, self._normal, out)

    def normalized_state(self) -> Any:
        """The scale-free global state of every episode, ``(B, N * n dim + 3)``, on the device.

        Per agent the row ``[z_i - mean_j z_j]`` component by component, component l times
        ``T_s^l`` (``[x_i - x̄, T_s (v_i - v̄)]`` for the double integrator), over
        ``max(D, tiny)``, agent major; then the clock ``t_k / T_s, T_{k+1} / T_s, k / K``. Every
        row entry is at most ``D`` in magnitude, so the rows lie in [-1, 1] by construction
        (clipped there only against rounding) and are all zero when ``D = 0``: invariant to a
        common shift and to the scale, like the normalized observations. For centralised critics.
        """
        return normalized_state(
            self.state, self.current_disagreement, self.clock, self.tables, self.backend, self.config
        )

    # ----------------------------------------------------------------- action
    def validate_actions(self, actions: object, name: str = "actions") -> Any:
        """A ``(B, N, 2 dim)`` real, finite action array; raise naming ``name`` otherwise.

        numpy: checked in full at once. torch: the shape and dtype are checked at once (they
        are known on the host); a non-finite entry sets :attr:`invalid` on the device (read
        by :meth:`raise_if_invalid`), so the check never waits on the device.
        """
        return self.backend.checked(actions, (self.n_episodes, self.config.n_agents, self.config.action_size), name)

    def raise_if_invalid(self) -> None:
        """Raise :class:`ArgumentError` if any episode saw a non-finite action or result (torch: one read off the device; the flags are then cleared, so it is reported once)."""
        self.backend.raise_if_invalid()

    def inputs_from_actions(self, actions: Any) -> tuple[Any, Any]:
        """Map actions to the affine input's end values ``(u(t_k+), u(t_{k+1}-))`` (the card's Action Space)."""
        return self.agents.inputs(self.plans_from_actions(actions), self.clock.interval(2), self.local_scale)

    def plans_from_actions(self, actions: Any) -> Any:
        """The actions as the agents take them: residuals plus the paper's plan (:meth:`~fxc_env.engine.observations.Observer.plans`)."""
        return self.observer.plans(actions, self.state, self.clock, self.graphs, self._uniform, self._normal)

    def step(self, actions: Any, raw_plans: bool = False) -> StepOutcome:
        """Play one interval with already validated ``(B, N, 2 dim)`` actions (``raw_plans``: double-integrator plans ``[a_x, a_v]`` in metres and m/s, whatever the action mode)."""
        self.clock.check_can_step()
        actions = actions if raw_plans else self.plans_from_actions(actions)
        interval = self.agents.advance(self.state, actions, self.clock, self.local_scale, self._spare, raw_plans)
        return self._conclude(interval, lambda: actions)

    def _conclude(self, interval: Any, actions: Callable[[], Any]) -> StepOutcome:
        """Adopt the played ``interval`` once finite (else refuse, naming ``actions()``), then move the clock, trackers and graphs."""
        self.state, self._spare = self.backend.commit_if_finite(
            self.state, interval, lambda: self.backend.refusal(actions(), interval, self.k, self.current_interval())
        )
        self.backend.flag(self.clock.past_deadline())
        reached = self.clock.advance()
        reward = self.trackers.update(interval, reached)
        self.observer.invalidate()
        self.graphs.draw(self.clock, self._switching_draw)
        terminated = self.episode_done() if self.clock.per_episode else self.clock.done
        return interval.outcome(reward, terminated)

    def step_reference(self) -> StepOutcome:
        """One interval of the paper's controller (eq. 11), ``step(ReferencePolicy(config)(observations()))`` to rounding, from the neighbour sums alone where the agents observe exactly (:mod:`~fxc_env.engine.reference`; else :class:`ArgumentError`)."""
        parts, plans = (self.state, self.clock, self.graphs), self.neighbour_plans
        interval = plans.interval(*parts, self.agents, self.local_scale, self._spare)
        return self._conclude(interval, lambda: plans.plans(*parts))

    # ---------------------------------------------------------------- metrics
    def batch_metrics(self) -> dict[str, np.ndarray]:
        """The metrics (docs: benchmark.md, "Baselines and the deadline benchmark") of every episode so far, one ``(B,)`` numpy array per :class:`EpisodeMetrics` field.

        Final values are those at each episode's current instant. On torch this reads the
        state off the device (call it at the end of an episode, not on the stepping path).
        """
        steps = to_host(self.clock.episode_steps(self.backend))
        return self.trackers.batch_metrics(self.state, steps, self.topologies, self.graphs.shared)

    def metric_tensors(self) -> dict[str, Any]:
        """The episode metrics that depend on the actions, ``(B,)`` arrays on the device (torch: differentiable).

        :meth:`EpisodeTrackers.metric_tensors <fxc_env.engine.trackers.EpisodeTrackers.metric_tensors>`:
        the same values as :meth:`batch_metrics`' columns of those names (to rounding), without a read off
        the device, so a loss built from them backpropagates to the actions.
        """
        return self.trackers.metric_tensors(self.state, self.clock.episode_steps(self.backend))

    def cut_graph(self) -> None:
        """torch: go on from the same values with no autograd history (truncated backpropagation).

        The state and the episode trackers become tensors that no longer record how they were
        computed, so a later ``backward()`` stops here. A full reset does this by itself; after a
        partial reset the episodes that go on keep their history until this is called. Nothing
        to do on numpy.
        """
        if self.is_numpy:
            return
        self.state = self.state.detach()
        self.trackers.detach()
        if self.agents.u_max is not None:
            self.agents.u_max = self.agents.u_max.detach()
        self.observer.detach()

    def episode_metrics(self, episode: int = 0) -> EpisodeMetrics:
        """The metrics of one episode so far (see :meth:`batch_metrics`); ``episode`` in ``[0, B)``."""
        episode = validation.integer("episode", episode, 0, self.n_episodes - 1)
        return EpisodeMetrics(**{name: column[episode].item() for name, column in self.batch_metrics().items()})
