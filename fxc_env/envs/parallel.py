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
        actions = policy(env.reset(seed=0)[0])  # {agent: action}, as every policy answers the env's dict

    ## Action Space
    ``Box(-b, b, (2 dim,), float64)`` per agent:

    | action_mode | obs_mode   | action                         | applied as                         | b    |
    |-------------|------------|--------------------------------|------------------------------------|------|
    | plan        | normalized | ``(alpha_x, alpha_v)``          | ``a_x = s alpha_x``, ``a_v = s alpha_v / T`` | 2 |
    | plan        | raw        | ``(a_x, a_v)`` metres, m/s      | as given                           | 1e3  |
    | plan_balanced | normalized | ``(alpha_x, alpha_v)``        | ``a_x = s alpha_x``, ``a_v = s alpha_v / T_s`` | 1 |
    | plan_balanced | raw      | ``(a_x, T_s a_v)`` metres, metres | ``a_v`` = the second over ``T_s`` | 1e3 |
    | accel       | normalized | ``(alpha_0, alpha_1)``          | ``u = s alpha / T^2`` at both ends | 10   |
    | accel       | raw        | ``(u(t_k+), u(t_{k+1}-))`` m/s^2 | as given                          | 1e9  |
    | residual    | normalized | ``(alpha_x, alpha_v)``, a correction to eq. (11)'s plan | ``a_x`` + ``s alpha_x``, ``a_v`` + ``s alpha_v / T_s`` | 2 |
    | residual    | raw        | ``(a_x, a_v)`` added to eq. (11)'s | as plan, raw                   | 1e3  |

    A plan ``(a_x, a_v)`` is the terminal change relative to coasting
    (``x(t_{k+1}) = x + T v + a_x``, ``v(t_{k+1}) = v + a_v``), realised by the minimum-energy
    affine input; ``accel`` is the straight line between the two ends; ``residual`` is a
    correction to the paper's plan (docs: results.md, "What learning reached", on its units).
    ``plan_balanced`` is ``plan`` in the deadline metric's units: one unit of either part moves
    ``D = e_x + T_s e_v`` by about ``s`` on every interval (``plan``'s ``alpha_v`` moves it by
    ``(T_s / T) s``, 1.6 to 330 times more on the paper's schedule), and its local scale weighs
    velocities by ``T_s`` too; the reference's plans measured on the v2 tasks lie within ``±0.81``
    (docs: environment.md, "Conditioning of the action").
    ``s = s_i`` is the agent's local scale below and ``T`` the coming interval. Actions outside
    the Box are applied as given (never clipped); the bounds hold the reference in normalised
    mode (``action_bound`` overrides them). A step whose energies would overflow float64 is
    refused (``actions``; docs: environment.md, "The environment", on exploring policies).

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
    larger. In ``normalized`` mode (default) rows are ``(x_j - x_i) / s_i`` and
    ``T (v_j - v_i) / s_i`` with the local scale ``s_i = max_j max(|x_j - x_i|, T |v_j - v_i|)``
    (components), so they lie in [-1, 1] (``plan_balanced``: ``T_s`` in place of ``T``, in both);
    ``obs_mode="raw"`` gives physical units;
    ``obs_format="dict"`` gives the parts as keys. No absolute position, no global information.
    Topology families draw a new graph set at every reset (``env.episode_edges()`` gives it).
    Docs: environment.md, "The environment" (the limit entry, families, float32 output).

    ## Rewards
    Team reward, the same for every agent: ``log(D(t_k) + f) - log(D(t_{k+1}) + f)`` with the
    disagreement ``D = e_x + T_s e_v``, ``e_x = max_ij ||x_i - x_j||_2`` (``e_v`` likewise) and
    ``f = reward_floor * D(0)``. It telescopes: the return is the log-reduction of
    disagreement achieved by the deadline.

    ## Starting State
    ``reset(seed, options={"x0": ..., "v0": ...})`` with arrays ``(N, dim)`` (or ``(N,)`` when
    ``dim = 1``); otherwise the scenario's initial state (``initial_state="random"`` drops
    it); otherwise positions ``U(-position_range, position_range)`` (5 m) and velocities
    ``U(-velocity_range, velocity_range)`` (2 m/s) per component from the env's generator.
    ``seed`` is None or an integer in ``[0, 2**128)``. The generator is made at the first
    ``reset`` and continues through unseeded resets, as in Gymnasium.

    ## Episode End
    Termination for every agent at ``t_K = T_s`` (after K steps; the clock is observed, so
    the deadline belongs to the task). Truncation only when ``max_cycles < K`` steps cut the
    episode earlier. ``step`` after the end raises ``RuntimeError``.

    ## Infos
    Per agent, at reset and after every step: ``t`` (seconds), ``interval`` (intervals done),
    ``energy`` (``integral |u_i|^2 dt`` on the last interval), ``peak_u`` (largest ``|u_i|``
    component on it), ``saturated_fraction`` (share of it at the limit ``u_max``); at the
    end also ``episode``: the fields of ``fxc_env.core.metrics.EpisodeMetrics``. Numbers only
    (``inf`` for never; a metric that does not apply is left out, never NaN), and every reset
    key is in every step's infos with the same type and shape. ``graph_tensors=True`` adds the
    coming interval's graph (docs: graph-tensors.md, "Graph tensors").

    ## State
    ``state()`` with ``global_state="raw"`` (default): ``(N, 2 dim)`` float64 rows
    ``[x_i, v_i]`` (absolute, unbounded). With ``global_state="normalized"`` (for centralised
    critics): the flat vector ``(N * 2 dim + 3,)`` in ``obs_dtype`` of rows
    ``[x_i - mean x, T_s (v_i - mean v)] / max(D, tiny)`` (agent major, in [-1, 1]) and the
    clock. ``state_space`` matches either form.

    ## Agent Models and Formations
    ``agent_model`` gives every agent, on each axis, ``z' = A z + B u`` (the double integrator
    is the default and keeps its closed forms); rows are then ``z_j - z_i`` and a ``plan``
    action is the change relative to free motion. ``formation_offsets`` make agents agree on
    ``z_i - e^{A t} h_i``. Docs: agent-models.md, "Agent models and formations".

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
    uint8; ``human``: shown in a pyplot window, None), at ``metadata["render_fps"]`` (docs:
    video.md, "Video"). Before the first ``reset`` it raises ``RuntimeError``; with
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
        #: Whether infos carry the current graph's ``edge_index`` and ``edge_attr`` (docs: graph-tensors.md, "Graph tensors").
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
        self.possible_agents = [f"agent_{i}" for i in range(self.config.n_agents)]
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
