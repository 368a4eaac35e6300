"""The PettingZoo parallel environment (the batch-of-one case of :class:`ConsensusEngine`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Unpack

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle
from pettingzoo import ParallelEnv

from fxc_env.config import RENDER_MODES, EnvConfig, check_max_cycles, check_render_mode, make_config
from fxc_env.config.arguments import (
    ENV_ARGUMENTS,
    FRONT_END_ARGUMENTS,
    GRAPH_TENSORS,
    EnvKwargs,
    env_arguments,
    env_signature,
    with_arguments_table,
)
from fxc_env.core import validation
from fxc_env.core.families import edge_lists
from fxc_env.engine import ConsensusEngine, with_initial_state
from fxc_env.envs.agent_dicts import (
    action_array,
    add_graph_info,
    episode_draw_info,
    episode_metrics_rows,
    initial_state_options,
    normalized_state,
    observation_dicts,
)
from fxc_env.envs.episode_view import EpisodeView
from fxc_env.envs.small_n import SmallInterval, applies, checked_values
from fxc_env.envs.spaces import action_space, observation_space, state_space


class ConsensusParallelEnv(ParallelEnv, EzPickle):
    """Fixed-time consensus of double integrators on directed graphs, sampled.

    ## Description
    N agents obey ``x_i' = v_i``, ``v_i' = u_i`` (``x_i, v_i, u_i`` in R^dim) and must agree on
    position and velocity by the deadline ``T_s`` (Liu, Zhao, Ren & Chen, "Fixed-time
    consensus of multiple double-integrator systems under directed topologies: a
    motion-planning approach"). Agents measure their in-neighbours only at the sampling
    instants ``t_k`` (paper schedule ``T_k = 6 T_s / (pi k)^2``, Section 3, last interval closing
    exactly at ``T_s``) and commit to an input that is affine in time until ``t_{k+1}``. Between
    instants the motion is integrated exactly (cubic x, quadratic v): no ODE solver, no
    time step. The graph switches periodically by sample index (``G_{k mod m}``).
    ``fxc_env.ReferencePolicy`` is the paper's controller, eq. (11); docs: environment.md ("The
    environment") walks through an episode. The shipped learned policies load into a plain
    environment, whatever its ``obs_slots`` or N (docs: training.md, "Training learned policies")::

        from fxc_env.policies.learned import load_learned_policy

        env = fxc_env.parallel_env(topology="ring", n_agents=20)  # obs_slots 1, the ring's in-degree
        policy = load_learned_policy("generalist", env)  # trained with 4 slots: same actions as there
        actions = {agent: policy(obs) for agent, obs in env.reset(seed=0)[0].items()}

    ## Action Space
    ``Box(-b, b, (2 dim,), float64)`` per agent:

    | action_mode | obs_mode   | action                         | applied as                         | b    |
    |-------------|------------|--------------------------------|------------------------------------|------|
    | plan        | normalized | ``(alpha_x, alpha_v)``          | ``a_x = s alpha_x``, ``a_v = s alpha_v / T`` | 2 |
    | plan        | raw        | ``(a_x, a_v)`` metres, m/s      | as given                           | 1e3  |
    | accel       | normalized | ``(alpha_0, alpha_1)``          | ``u = s alpha / T^2`` at both ends | 10   |
    | accel       | raw        | ``(u(t_k+), u(t_{k+1}-))`` m/s^2 | as given                          | 1e9  |
    | residual    | normalized | ``(alpha_x, alpha_v)``, a correction to eq. (11)'s plan | ``a_x`` + ``s alpha_x``, ``a_v`` + ``s alpha_v / T_s`` | 2 |
    | residual    | raw        | ``(a_x, a_v)`` added to eq. (11)'s | as plan, raw                   | 1e3  |

    A plan ``(a_x, a_v)`` is the terminal change relative to coasting
    (``x(t_{k+1}) = x + T v + a_x``, ``v(t_{k+1}) = v + a_v``), realised by the minimum-energy
    affine input. In ``accel`` mode the input is the straight line between the two ends
    (equal ends: zero-order hold). In ``residual`` mode the action is a correction added to the
    paper's plan (eq. 11), computed from the same rows, mask and scale the agent observes: the
    zero action is the reference (``ReferencePolicy`` then emits zeros; double integrators only;
    the Box bounds the correction). Normalized, the velocity correction is in units of
    ``s / T_s``, not the plan's ``s / T``: D weighs velocities by ``T_s``, so one unit of either
    part moves D by about ``s`` on every interval of the schedule (with ``s / T``, up to
    ``(pi k)^2 / 6 = 6.6e4`` times more on the paper schedule's last one at K = 200; measured
    in the docs: results.md, "PPO from scratch around the reference"). Raw corrections are in metres and m/s.
    ``s = s_i`` is the agent's local scale below and ``T`` the coming interval. Actions outside the Box are applied as given (never clipped); the
    bounds hold the reference in normalised mode for every state. Raw bounds are nominal:
    they hold it from the documented initial ranges on the built-in topologies up to
    N = 100 (``action_bound`` overrides them). Any real dtype is accepted.

    Exploring policies: uniform random actions over the whole normalised box can multiply the
    disagreement by up to about ``1 + 2 b`` per interval, and the paper schedule's energies grow
    like ``T^-3`` as the intervals shrink, so over long episodes they overflow float64 and the step
    is refused (``actions``: the state is unchanged and ``reset`` starts afresh). Measured on
    ``paper_fig1`` at K = 2000 with seeded box-uniform actions: refused near step 630 with
    ``b = 2``, near 1,900 with ``b = 0.5``; ``action_bound=0.25`` finishes. Explore with a smaller
    ``action_bound``, the uniform schedule, or a policy that starts near the reference (as the
    shipped gain networks do).

    ## Observation Space
    Flat ``Box`` of size ``d_max * 2 dim + d_max + 3`` (``+ 1`` with ``u_max``) per agent,
    measured at ``t_k``, in ``obs_dtype`` (float64 by default):

    | part  | size            | content                                                          |
    |-------|-----------------|------------------------------------------------------------------|
    | rows  | ``d_max * 2 dim`` | per in-neighbour j of ``G_k`` (ascending): ``[x_j - x_i, v_j - v_i]``, zero padded |
    | mask  | ``d_max``       | 1 for a real row, 0 for padding                                  |
    | clock | 3               | ``t_k / T_s``, ``T_{k+1} / T_s``, ``k / K``                      |
    | limit | 1, with ``u_max`` | how far the input limit binds on the coming interval, in [-1, 1] (``fxc_env.engine.limit_feature``) |

    ``d_max`` is the largest in-degree over the topology set, or ``obs_slots`` when that is
    larger (room for other topologies, so one policy fits several). In ``normalized`` mode (default)
    rows are ``(x_j - x_i) / s_i`` and ``T (v_j - v_i) / s_i`` with the local scale
    ``s_i = max_j max(|x_j - x_i|, T |v_j - v_i|)`` (components), so they lie in [-1, 1]; an
    agent with ``s_i = 0`` sees zeros and coasts whatever it does. ``obs_mode="raw"``
    gives physical units. ``obs_format="dict"`` gives ``{"neighbours": (d_max, 2 dim),
    "mask": (d_max,), "clock": (3,)}`` (and ``"input_limit": (1,)``) instead. No absolute position, no global information.
    The engine always computes in float64; ``obs_dtype="float32"`` casts at the output. With raw
    float32 observations no entry becomes ``inf``: states start within ``±1e37`` and a step that
    would take two agents further apart than float32's range (3.4e38) is refused naming ``actions``
    (state unchanged).

    The limit entry is ``l / (1 + |l|)`` with ``l = log10(u_max T^2 / s_i)``: ``u_max T^2 / s_i``
    compares the limit with the input a plan at the agent's scale needs (eq. 11 starts an
    interval at about ``6 e / T^2``, at most ``10 s_i / T^2``), decades spread evenly (0 where
    they are equal, ±0.5 a decade either way), bounded without a hard clip, 1 when
    ``s_i = 0``; scaling the state and ``u_max`` together leaves it unchanged.

    A topology *family* (``topology={"family": ...}`` or a mixture, see
    ``fxc_env.core.families``) draws a new graph set at every reset from the episode's seed:
    rings, paths and stars with random agent labels, complete graphs, random digraphs with a
    mean in-degree drawn from a range; a switching period ``m`` drawn from a range deals the
    union's edges to ``m`` graphs, so only the union need span (Theorem 2). Every draw spans
    jointly by construction. ``env.episode_edges()`` gives the episode's graphs (lists of ``[j, i]``
    pairs; ``topology=env.episode_edges()`` replays the episode on a fixed topology); a ``u_max``
    drawn from a set is in every info (``u_max``).

    ## Rewards
    Team reward, the same for every agent: ``log(D(t_k) + f) - log(D(t_{k+1}) + f)`` with the
    disagreement ``D = e_x + T_s e_v``, ``e_x = max_ij ||x_i - x_j||_2`` (``e_v`` likewise) and
    ``f = reward_floor * D(0)``. It telescopes: the return is the log-reduction of
    disagreement achieved by the deadline.

    ## Starting State
    ``reset(seed, options={"x0": ..., "v0": ...})`` with arrays ``(N, dim)`` (or ``(N,)`` when
    ``dim = 1``); otherwise the scenario's initial state (``initial_state="random"`` drops
    it); otherwise positions
    ``U(-position_range, position_range)`` (5 m) and velocities ``U(-velocity_range,
    velocity_range)`` (2 m/s) per component from the env's generator. Other option keys
    are ignored, as in Gymnasium. ``seed`` is None or an integer in ``[0, 2**128)``.
    The generator is made at the first ``reset`` (from ``seed``, else from fresh entropy)
    and continues through unseeded resets, as in Gymnasium: copies of an env that was never
    reset draw independent episodes.

    ## Episode End
    Termination for every agent at ``t_K = T_s`` (after K steps; the clock is observed, so
    the deadline belongs to the task). Truncation only when ``max_cycles < K`` steps cut the
    episode earlier. ``step`` after the end raises ``RuntimeError``.

    ## Infos
    Per agent, at reset and after every step: ``t`` (seconds), ``interval`` (intervals done),
    ``energy`` (``integral |u_i|^2 dt`` on the last interval), ``peak_u`` (largest ``|u_i|``
    component on it), ``saturated_fraction`` (share of it at the limit ``u_max``); at the
    end also ``episode``: the episode's metrics (the fields of
    ``fxc_env.core.metrics.EpisodeMetrics``: deadline error ``D(T_s)/D(0)``, spreads,
    settling times ``t_eps``, energy, peak input, Theorem 2's predicted and the achieved
    final values; docs: getting-started.md, "Getting started"). Numbers only, each agent its own dict:
    ``inf`` for a threshold never reached; a metric that does not apply to the episode
    (``predicted_*`` and the intervals bounds ``radius_bound``, ``all_roots_bound`` with random
    switching, the bounds above 2000 agents, ``energy_ratio`` where ``E* = 0``) is left out of the dict rather
    than ``nan``, so no info value is ever NaN and two identically seeded runs give equal
    infos.

    Every key of the reset infos is in every step's infos with the same type and shape (what
    replay buffers such as Tianshou's need); only ``episode`` joins at the end. Variable-length
    data stays out: the episode's graphs are ``env.episode_edges()``.

    **Graph tensors** (``graph_tensors=True``, for graph neural networks; docs: graph-tensors.md, "Graph
    tensors"): every info at reset and after every step also holds the coming interval's graph
    in PyTorch Geometric's convention, padded to a fixed ``E`` (``edge_capacity``) with the
    edge ``N -> N``: ``edge_index`` ``(2, E)`` int64 (source j, target i), ``edge_mask`` ``(E,)``,
    ``n_edges`` (an int) and ``edge_attr`` ``(E, n dim)`` (each edge's observation row), the same
    arrays in every agent's dict (:mod:`fxc_env.engine.graph_tensors` says how padding keeps a
    summing message pass exact). They are infos, not observations: the graph is global while an
    observation is one agent's local measurement, and the observation spaces stay fixed Boxes.

    ## State
    ``state()`` with ``global_state="raw"`` (default): ``(N, 2 dim)`` float64 rows
    ``[x_i, v_i]`` (absolute, unbounded). With ``global_state="normalized"`` (for centralised
    critics): the flat vector ``(N * 2 dim + 3,)`` in ``obs_dtype`` of rows
    ``[x_i - mean x, T_s (v_i - mean v)] / max(D, tiny)`` (agent major) and the clock. Each
    row entry is at most ``D`` in magnitude, so the rows lie in [-1, 1] by construction
    (clipped there only against rounding; all zero once ``D = 0``), and the clock in [0, 1]:
    scale-free and invariant to a common shift of positions or velocities, like the
    normalized observations. ``state_space`` matches either form.

    ## Agent Models and Formations
    ``agent_model`` gives every agent, on each axis, ``z' = A z + B u`` with ``z`` in R^n (the
    double integrator's ``z = (x, v)`` is the default and keeps its closed forms). Rows are
    then ``z_j - z_i`` (``n dim`` numbers, component-major), and a ``plan`` action is ``Delta``,
    the terminal change relative to free motion (``n dim`` numbers), applied as the
    minimum-energy input ``u(s) = B^T e^{A^T (T - s)} G(T)^{-1} Delta`` (Gramian ``G``; matrix
    exponentials, no ODE solver). Normalized units read component l in position units,
    ``r_l |z_j - z_i|_l`` with ``r = (1, T, T^2, ...)`` for integrator chains (in general
    ``D_0 / D_l`` of the time-scaled frame ``D = h^levels``, ``h = min(T, 1 / rho(A))``);
    ``s_i`` is their largest value and ``Delta_l = s_i alpha_l / r_l``, so the task stays
    scale-free. The reference plans ``Delta_i = e^{A T} e_i`` with ``e_i`` the mean of
    ``z_j - z_i`` over itself and its in-neighbours (eq. 11 for the double integrator); the
    interval map is ``Z+ = (W_k kron e^{A T_k}) Z``, so Theorems 1-2 carry over: under their
    spanning conditions every agent reaches ``z*(T_s) = e^{A T_s} sum_j xi_j z_j(0)`` and
    follows ``z*(t) = e^{A t} sum_j xi_j z_j(0)`` afterwards. The disagreement is
    ``D = sum_l T_s^l e_{z_l}``. With ``formation_offsets`` ``h_i`` agents agree on
    ``z_i - e^{A t} h_i`` instead: observations, rewards and metrics are of that formation
    error, ``state()`` and frames of the absolute states. ``accel`` actions and ``u_max`` are
    the double integrator's.

    ## Arguments
    Every argument is keyword-only except ``scenario``; defaults in brackets come from the
    scenario when one is named (explicit arguments override it). The table is
    ``fxc_env.config.arguments.ENV_ARGUMENTS``, which every front end and the ``fxc`` flags share.

    {arguments table}

    The realism options (``u_max`` to ``switching``; docs: realism.md, "Realism options") are off by
    default and draw from the env's generator. Every bad argument raises
    :class:`~fxc_env.core.validation.ArgumentError` (a ``ValueError``; a ``TypeError`` too
    for a wrong type) naming it, and leaves a live env unchanged.

    ## Rendering
    ``render()`` returns the frame of the episode so far (``rgb_array``: ``(360, 640, 3)``
    uint8; ``human``: shown in a pyplot window, None, which needs an interactive matplotlib
    backend: under a headless one such as Agg matplotlib warns and nothing is shown). A frame
    draws the trails through the sampling instants so far (position against time in 1-D, the
    plane of the first two axes otherwise), the current interval's graph as arrows ``j -> i``,
    the clock and ``D(t_k)/D(0)`` (docs: video.md, "Video"). Call it after ``reset`` and after each step,
    as Gymnasium's ``RecordVideo`` does, at ``metadata["render_fps"]``; nothing is recorded
    while ``render_mode`` is None. Before the first ``reset`` there is no episode: it raises
    ``RuntimeError`` (as PettingZoo's and Gymnasium's order enforcing do). With
    ``render_mode=None`` it warns and returns None.

    ## Copies
    ``pickle`` and ``copy.deepcopy`` keep the whole state: a copy made mid-episode continues
    bit for bit, generator included. The constructor arguments are recorded the
    ``gymnasium.utils.EzPickle`` way (``_ezpickle_kwargs``) but not re-applied on unpickling,
    which would lose the episode and redraw a ``topology_seed=None`` topology.

    ## Version History
    * v0: initial release.
    """

    __doc__ = with_arguments_table(__doc__, (*ENV_ARGUMENTS, *FRONT_END_ARGUMENTS, GRAPH_TENSORS))

    metadata = {
        "name": "fxc_consensus_v0",
        "render_modes": list(RENDER_MODES),
        "render_fps": 10,
        "is_parallelizable": True,
    }
    #: Whether a reset may take the small-N path (:mod:`fxc_env.envs.small_n`: the same numbers
    #: for few agents, faster); False plays every interval through the engine (for comparisons).
    small_n_path: bool = True
    #: The small-N path of the episode, or None (set at every reset).
    _small: SmallInterval | None = None

    @env_signature(after=(*FRONT_END_ARGUMENTS, GRAPH_TENSORS))
    def __init__(
        self,
        scenario: str | None = None,
        *,
        render_mode: str | None = None,
        max_cycles: int | None = None,
        graph_tensors: bool = False,
        **kwargs: Unpack[EnvKwargs],
    ) -> None:
        arguments = env_arguments(locals(), kwargs)
        check_render_mode(render_mode)
        check_max_cycles(max_cycles)
        #: Whether infos carry the current graph's ``edge_index`` and ``edge_attr`` (Infos, Graph tensors).
        self.graph_tensors = GRAPH_TENSORS.check(graph_tensors)
        self.config: EnvConfig = make_config(**arguments)
        EzPickle.__init__(
            self, **arguments, render_mode=render_mode, max_cycles=max_cycles, graph_tensors=graph_tensors
        )
        self.render_mode = render_mode
        self.max_cycles = max_cycles
        self._build()

    def _build(self) -> None:
        """The engine, the agents and their spaces, and the episode's bookkeeping, of :attr:`config`."""
        self.engine = ConsensusEngine(self.config, n_episodes=1)
        n = self.config.n_agents
        self.possible_agents = [f"agent_{i}" for i in range(n)]
        self.agents: list[str] = []
        self._agent_index = {agent: i for i, agent in enumerate(self.possible_agents)}
        self._agent_set = set(self.possible_agents)
        #: The episode generator, made at the first reset (so copies of a fresh env differ).
        self._rng: np.random.Generator | None = None
        self._has_reset = False
        self._steps = 0
        #: What the reset drew that every info of the episode carries (:func:`episode_draw_info`).
        self._drawn: dict[str, Any] = {}
        obs_space, act_space = observation_space(self.config), action_space(self.config)
        self.observation_spaces = dict.fromkeys(self.possible_agents, obs_space)
        self.action_spaces = dict.fromkeys(self.possible_agents, act_space)
        self.state_space = state_space(self.config)
        self._view = EpisodeView(self.config, self.render_mode)

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[agent]

    # ---------------------------------------------------------------- pickle
    def __getstate__(self) -> dict[str, Any]:
        return self.__dict__.copy()  # the whole state (EzPickle's default would rebuild a fresh env)

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # ------------------------------------------------------------------ reset
    def reset(
        self, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        # Every argument is checked before anything changes.
        seed = validation.optional_seed("seed", seed)
        x0, v0 = initial_state_options(self.engine, options)
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(seed)
        draw = self.engine.draw_episode(self._rng)  # the family's topology and u_max when drawn, x0, v0
        draw = with_initial_state(draw, x0, v0)
        self.engine.reset_from_draws([draw], rng=self._rng)
        if not self.small_n_path or not applies(self.config, self.engine):
            self._small = None
        elif self._small is None:
            self._small = SmallInterval(self.config, self.engine)
        self.agents = self.possible_agents[:]
        self._steps = 0
        self._has_reset = True
        self._view.start(self.engine)
        # The same numeric keys as every step's infos (consumers such as TorchRL read the schema here).
        infos = {
            agent: {"t": 0.0, "interval": 0, "energy": 0.0, "peak_u": 0.0, "saturated_fraction": 0.0}
            for agent in self.agents
        }
        self._drawn = episode_draw_info(draw)
        for info in infos.values():
            info.update(self._drawn)
        if self.render_mode == "human":
            self.render()
        flat = self._flat_observations()
        if self.graph_tensors:
            add_graph_info(infos, self.engine, flat)
        return self._observe(flat), infos

    def _flat_observations(self) -> np.ndarray:
        """Every agent's flat observation ``(N, obs_size)`` in ``obs_dtype``."""
        if self._small is not None:
            return self._small.observations(self.engine)
        return self.engine.observations()[0].astype(self.config.observation_dtype, copy=False)

    def episode_edges(self) -> list[list[list[int]]]:
        """The episode's graphs ``G_0 .. G_{m-1}`` as lists of ``[j, i]`` pairs (j -> i: i measures j).

        A topology family draws new graphs at every reset; ``topology=env.episode_edges()`` replays
        the episode on that fixed topology. Not an info: its length changes from draw to draw.
        """
        if not self._has_reset:
            raise RuntimeError("episode_edges: there is no episode yet; call reset() first")
        return edge_lists(self.engine.topologies[0])

    def _observe(self, obs: np.ndarray | None = None) -> dict[str, Any]:
        flat = self._flat_observations() if obs is None else obs
        return observation_dicts(flat, self.config, self._agent_index)

    # ------------------------------------------------------------------- step
    def check_action(self, agent: str, action: Any, name: str | None = None) -> np.ndarray:
        """One agent's action as a float64 ``(2 dim,)`` array; raise naming ``name`` (``actions[agent]``) if bad."""
        name = f"actions[{agent!r}]" if name is None else name
        return validation.action_array(name, action, (self.config.action_size,))

    def _action_array(self, actions: Any) -> np.ndarray:
        return action_array(actions, self.possible_agents, self._agent_set, self.config.action_size, self.check_action)

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("step: the episode has ended (or reset() was never called); call reset() first")
        engine = self.engine
        small = self._small
        played = None
        if small is not None:
            # The small-N path (fxc_env.envs.small_n): the same numbers without numpy's per-call cost.
            values = checked_values(actions, self.possible_agents, small.action_size)
            if values is None:
                values = self._action_array(actions).ravel().tolist()
            played = small.step(engine, values)
            if played is None:  # what the small path leaves to the engine (it refuses overflow, unchanged)
                array = np.array(values).reshape(1, small.n, small.action_size)
        else:
            array = self._action_array(actions)
        if played is None:
            outcome = engine.step(array)
            reward, terminated = float(outcome.reward[0]), outcome.terminated
            energy, peak = outcome.energy[0].tolist(), outcome.peak_input[0].tolist()
            saturated = outcome.saturated_fraction[0].tolist()
        else:
            reward, energy, peak = played
            terminated, saturated = engine.done, [0.0] * len(energy)
        self._steps += 1
        truncated = not terminated and self.max_cycles is not None and self._steps >= self.max_cycles
        t, interval = engine.time, engine.k
        rewards = dict.fromkeys(self.agents, reward)
        terminations = dict.fromkeys(self.agents, terminated)
        truncations = dict.fromkeys(self.agents, truncated)
        infos = {
            agent: {"t": t, "interval": interval, "energy": e, "peak_u": p, "saturated_fraction": f}
            for agent, e, p, f in zip(self.possible_agents, energy, peak, saturated, strict=True)
        }
        if self._drawn:
            for info in infos.values():
                info.update(self._drawn)
        if terminated or truncated:
            episode = episode_metrics_rows(engine)[0]
            for info in infos.values():
                info["episode"] = dict(episode)  # each agent its own copy
        flat = self._flat_observations()
        if self.graph_tensors:
            add_graph_info(infos, self.engine, flat)
        observations = self._observe(flat)
        if self.render_mode is not None:
            self._view.record(engine)
        if self.render_mode == "human":
            self.render()
        if terminated or truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    # ------------------------------------------------------------------ state
    def state(self) -> np.ndarray:
        """The global state (see State in the class docstring): raw ``(N, 2 dim)`` or normalized ``(N * 2 dim + 3,)``.

        Before the first ``reset`` there is no episode: ``RuntimeError``, as ``render``.
        """
        if not self._has_reset:
            raise RuntimeError("state: there is no episode yet; call reset() first")
        if self.config.global_state == "normalized":
            return normalized_state(self.engine)[0]
        return np.array(self.engine.absolute_state()[0].reshape(self.config.n_agents, -1))

    # ---------------------------------------------------------------- render
    def render(self) -> np.ndarray | None:
        """The frame of the episode so far (see Rendering in the class docstring)."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render: called with render_mode=None; build the env with render_mode='rgb_array' or 'human'"
            )
            return None
        if not self._has_reset:
            raise RuntimeError("render: there is no episode to draw yet; call reset() first")
        return self._view.frame()

    def close(self) -> None:
        self._view.close()
