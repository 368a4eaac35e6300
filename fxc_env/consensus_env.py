"""The PettingZoo parallel environment (the batch-of-one case of :class:`ConsensusEngine`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from fxc_env.config import RENDER_MODES, EnvConfig, check_max_cycles, check_render_mode, make_config
from fxc_env.core.validation import ArgumentError, ArgumentTypeError
from fxc_env.engine import ConsensusEngine
from fxc_env.rendering import EpisodeView
from fxc_env.spaces import action_space, observation_space, state_space


class ConsensusParallelEnv(ParallelEnv):
    """Fixed-time consensus of double integrators on directed graphs, sampled.

    ## Description
    N agents obey ``x_i' = v_i``, ``v_i' = u_i`` (``x_i, v_i, u_i`` in R^dim) and must agree on
    position and velocity by the deadline ``T_s`` (Liu, Zhao, Ren & Chen, "Fixed-time
    consensus of multiple double-integrator systems under directed topologies: a
    motion-planning approach"). Agents measure their in-neighbours only at the sampling
    instants ``t_k`` (paper schedule ``T_k = 6 T_s / (pi k)^2``, last interval closing exactly
    at ``T_s``) and commit to an input that is affine in time until ``t_{k+1}``. Between
    instants the motion is integrated exactly (cubic x, quadratic v): no ODE solver, no
    time step. The graph switches periodically by sample index (``G_{k mod m}``).
    ``fxc_env.ReferencePolicy`` is the paper's controller, eq. (11).

    ## Action Space
    ``Box(-b, b, (2 dim,), float64)`` per agent:

    | action_mode | obs_mode   | action                         | applied as                         | b    |
    |-------------|------------|--------------------------------|------------------------------------|------|
    | plan        | normalized | ``(alpha_x, alpha_v)``          | ``a_x = s alpha_x``, ``a_v = s alpha_v / T`` | 2 |
    | plan        | raw        | ``(a_x, a_v)`` metres, m/s      | as given                           | 1e3  |
    | accel       | normalized | ``(alpha_0, alpha_1)``          | ``u = s alpha / T^2`` at both ends | 10   |
    | accel       | raw        | ``(u(t_k+), u(t_{k+1}-))`` m/s^2 | as given                          | 1e9  |

    A plan ``(a_x, a_v)`` is the terminal change relative to coasting
    (``x(t_{k+1}) = x + T v + a_x``, ``v(t_{k+1}) = v + a_v``), realised by the minimum-energy
    affine input. In ``accel`` mode the input is the straight line between the two ends
    (equal ends: zero-order hold). ``s = s_i`` is the agent's local scale below and ``T`` the
    coming interval. Actions outside the Box are applied as given (never clipped); the
    bounds hold the reference in normalised mode for every state. Raw bounds are nominal:
    they hold it from the documented initial ranges on the built-in topologies up to
    N = 100 (``action_bound`` overrides them).

    ## Observation Space
    Flat ``Box(float64)`` of size ``d_max * 2 dim + d_max + 3`` per agent, measured at ``t_k``:

    | part  | size            | content                                                          |
    |-------|-----------------|------------------------------------------------------------------|
    | rows  | ``d_max * 2 dim`` | per in-neighbour j of ``G_k`` (ascending): ``[x_j - x_i, v_j - v_i]``, zero padded |
    | mask  | ``d_max``       | 1 for a real row, 0 for padding                                  |
    | clock | 3               | ``t_k / T_s``, ``T_{k+1} / T_s``, ``k / K``                      |

    ``d_max`` is the largest in-degree over the topology set, or ``obs_slots`` when that is
    larger (room for other topologies, so one policy fits several). In ``normalized`` mode (default)
    rows are ``(x_j - x_i) / s_i`` and ``T (v_j - v_i) / s_i`` with the local scale
    ``s_i = max_j max(|x_j - x_i|, T |v_j - v_i|)`` (components), so they lie in [-1, 1]; an
    agent with ``s_i = 0`` sees zeros and coasts whatever it does. ``obs_mode="raw"``
    gives physical units. ``obs_format="dict"`` gives ``{"neighbours": (d_max, 2 dim),
    "mask": (d_max,), "clock": (3,)}`` instead. No absolute position, no global information.

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
    velocity_range)`` (2 m/s) per component from the seeded generator. Other option keys
    are ignored, as in Gymnasium.

    ## Episode End
    Termination for every agent at ``t_K = T_s`` (after K steps; the clock is observed, so
    the deadline belongs to the task). Truncation only when ``max_cycles < K`` steps cut the
    episode earlier. ``step`` after the end raises ``RuntimeError``.

    ## Infos
    Per agent, at reset and after every step: ``t`` (seconds), ``interval`` (intervals done),
    ``energy`` (``integral |u_i|^2 dt`` on the last interval), ``peak_u`` (largest ``|u_i|``
    component on it), ``saturated_fraction`` (share of it at the limit ``u_max``); at the
    end also ``episode``: SPEC 5 metrics (``EpisodeMetrics.as_dict()``).

    ## State
    ``state()``: ``(N, 2 dim)`` float64 rows ``[x_i, v_i]``; ``state_space`` matches.

    ## Arguments
    ``scenario`` (named bundle, e.g. ``"paper_fig1"``), ``n_agents`` [6], ``topology``
    [``"paper_fig1"``: the **assumed** Fig. 1], ``settling_time`` [20.0 s], ``n_intervals`` K
    [200], ``schedule`` [``"paper"``], ``dim`` [1], ``action_mode`` [``"plan"``], ``obs_mode``
    [``"normalized"``], ``obs_format`` [``"flat"``], ``initial_state`` [random],
    ``render_mode`` [None], ``max_cycles`` [None], ``obs_slots`` [d_max], ``action_bound``, ``reward_floor``
    [1e-12], ``position_range`` [5.0], ``velocity_range`` [2.0], ``topology_seed`` [0],
    ``mean_in_degree`` [2.0] and ``topology_period`` [1] for ``random``.
    Realism (all off by default, seeded with the env): ``u_max`` [None] clips each input
    component to ±u_max m/s^2, integrated exactly (infos report the saturated share);
    ``obs_noise`` [0] Gaussian noise (m, m/s) on each relative measurement; ``link_dropout``
    [0] probability that an edge is lost at a sampling instant (the mask shows it);
    ``switching`` [``"periodic"``] or ``"random"`` (each interval's graph drawn from the set).
    Every bad argument raises an exception naming it, and leaves a live env unchanged.

    ## Version History
    * v0: initial release.
    """

    metadata = {
        "name": "fxc_consensus_v0",
        "render_modes": list(RENDER_MODES),
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(self, render_mode: str | None = None, max_cycles: int | None = None, **kwargs: Any) -> None:
        check_render_mode(render_mode)
        check_max_cycles(max_cycles)
        self.config: EnvConfig = make_config(**kwargs)
        self.render_mode = render_mode
        self.max_cycles = max_cycles
        self.engine = ConsensusEngine(self.config, n_episodes=1)
        n = self.config.n_agents
        self.possible_agents = [f"agent_{i}" for i in range(n)]
        self.agents: list[str] = []
        self._agent_index = {agent: i for i, agent in enumerate(self.possible_agents)}
        self._agent_set = set(self.possible_agents)
        self._rng = np.random.default_rng()
        obs_space, act_space = observation_space(self.config), action_space(self.config)
        self.observation_spaces = dict.fromkeys(self.possible_agents, obs_space)
        self.action_spaces = dict.fromkeys(self.possible_agents, act_space)
        self.state_space = state_space(self.config)
        self._view = EpisodeView(self.config, render_mode)

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[agent]

    # ------------------------------------------------------------------ reset
    def reset(
        self, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        if options is not None and not isinstance(options, Mapping):
            raise ArgumentTypeError(f"options: expected a dict or None, got {type(options).__name__}")
        options = options or {}
        x0 = self.engine.validate_state("options['x0']", options["x0"]) if "x0" in options else None
        v0 = self.engine.validate_state("options['v0']", options["v0"]) if "v0" in options else None
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        drawn_x, drawn_v = self.engine.sample_initial_state(self._rng)
        x0 = drawn_x if x0 is None else x0
        v0 = drawn_v if v0 is None else v0
        self.engine.reset(x0[None], v0[None], rng=self._rng)
        self.agents = self.possible_agents[:]
        self._steps = 0
        self._view.start(x0, v0)
        # The same numeric keys as every step's infos (consumers such as TorchRL read the schema here).
        infos = {
            agent: {"t": 0.0, "interval": 0, "energy": 0.0, "peak_u": 0.0, "saturated_fraction": 0.0}
            for agent in self.agents
        }
        if self.render_mode == "human":
            self.render()
        return self._observe(), infos

    def _observe(self) -> dict[str, Any]:
        obs = self.engine.observations()[0]
        if self.config.obs_format == "dict":
            layout = self.config.layout
            rows, mask, clock = (
                obs[:, : layout.rows_end],
                obs[:, layout.rows_end : layout.mask_end],
                obs[:, layout.mask_end :],
            )
            rows = rows.reshape(len(obs), layout.slots, layout.row_size)
            return {
                agent: {"neighbours": rows[i], "mask": mask[i], "clock": clock[i]}
                for agent, i in self._agent_index.items()
            }
        return {agent: obs[i] for agent, i in self._agent_index.items()}

    # ------------------------------------------------------------------- step
    def _action_array(self, actions: Any) -> np.ndarray:
        if type(actions) is not dict and not isinstance(actions, Mapping):
            raise ArgumentTypeError(f"actions: expected a dict from agent name to action, got {type(actions).__name__}")
        if actions.keys() != self._agent_set:  # every agent is live while the episode runs
            unknown = sorted(set(actions) - self._agent_set, key=str)
            if unknown:
                raise ArgumentError(
                    f"actions: unknown agent(s) {unknown}; expected keys agent_0 .. agent_{len(self.possible_agents) - 1}"
                )
            missing = [agent for agent in self.agents if agent not in actions]
            raise ArgumentError(f"actions: missing an action for agent(s) {missing}")
        size = self.config.action_size
        try:
            stacked = np.array([actions[agent] for agent in self.possible_agents])
        except (TypeError, ValueError):
            stacked = None  # ragged: the loop below names the agent
        array = stacked.astype(np.float64) if stacked is not None and stacked.dtype.kind in "biuf" else None
        if array is None or array.shape != (len(self.possible_agents), size) or not np.isfinite(array).all():
            for agent in self.possible_agents:
                action = np.asarray(actions[agent])
                if action.dtype.kind not in "biuf":
                    raise ArgumentTypeError(f"actions[{agent!r}]: expected real numbers, got {action!r}")
                if action.shape != (size,):
                    raise ArgumentError(f"actions[{agent!r}]: expected shape ({size},), got {action.shape}")
                if not np.all(np.isfinite(action)):
                    raise ArgumentError(f"actions[{agent!r}]: every entry must be finite (no NaN or inf), got {action}")
        return array[None]

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("step: the episode has ended (or reset() was never called); call reset() first")
        array = self._action_array(actions)
        outcome = self.engine.step(array)
        self._steps += 1
        engine = self.engine
        terminated = outcome.terminated
        truncated = not terminated and self.max_cycles is not None and self._steps >= self.max_cycles
        t = engine.time
        reward = float(outcome.reward[0])
        rewards = dict.fromkeys(self.agents, reward)
        terminations = dict.fromkeys(self.agents, terminated)
        truncations = dict.fromkeys(self.agents, truncated)
        energy, peak = outcome.energy[0].tolist(), outcome.peak_input[0].tolist()
        saturated = outcome.saturated_fraction[0].tolist()
        infos = {
            agent: {
                "t": t,
                "interval": engine.k,
                "energy": energy[i],
                "peak_u": peak[i],
                "saturated_fraction": saturated[i],
            }
            for agent, i in self._agent_index.items()
        }
        if terminated or truncated:
            episode = engine.episode_metrics(0).as_dict()
            for info in infos.values():
                info["episode"] = episode
        observations = self._observe()
        self._view.record(t, engine.x[0], engine.v[0])
        if self.render_mode == "human":
            self.render()
        if terminated or truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    # ------------------------------------------------------------------ state
    def state(self) -> np.ndarray:
        """Global state ``(N, 2 dim)``: rows ``[x_i, v_i]``."""
        return np.concatenate([self.engine.x[0], self.engine.v[0]], axis=-1)

    # ---------------------------------------------------------------- render
    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render: called with render_mode=None; build the env with render_mode='rgb_array' or 'human'"
            )
            return None
        return self._view.frame(int(self.engine.graph_indices()[0]))

    def close(self) -> None:
        self._view.close()
