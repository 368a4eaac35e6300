"""A native stable-baselines3 ``VecEnv`` with parameter sharing over every agent.

One :class:`ConsensusEngine` runs ``n_envs`` episodes in lock step; each of their N agents
is one SB3 sub-environment, so a single policy acts for all ``n_envs * N`` agents in one
vectorised call. Stepping is array code; the only per-step Python work that grows with
``num_envs`` is the list of info dicts SB3's contract asks for. SuperSuit's generic route
(``pettingzoo_env_to_vec_env_v1`` then ``concat_vec_envs_v1``) also trains on the parallel
environment, but it steps every agent through Python dicts, and SB3's ``seed``,
``get_attr`` and ``set_attr`` do not reach the environments through it.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any, Unpack

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from fxc_env.config import EnvConfig, check_max_cycles, check_render_mode, make_config
from fxc_env.config.arguments import (
    ENV_ARGUMENTS,
    FRONT_END_ARGUMENTS,
    REQUIRED,
    Argument,
    EnvKwargs,
    env_arguments,
    env_signature,
    with_arguments_table,
)
from fxc_env.core import validation
from fxc_env.core.families import edge_lists
from fxc_env.core.validation import ArgumentError, ArgumentTypeError
from fxc_env.engine import ConsensusEngine, EpisodeDraw, StepOutcome, with_initial_state
from fxc_env.envs.agent_dicts import episode_draw_info, episode_metrics_rows, initial_state_options, normalized_state
from fxc_env.envs.episode_view import EpisodeView
from fxc_env.envs.parallel import ConsensusParallelEnv
from fxc_env.envs.rendering import GRID_EPISODES, blank_frame
from fxc_env.envs.spaces import action_space, observation_space

#: Attributes of a :class:`ConsensusVecEnv` that :meth:`~ConsensusVecEnv.set_attr` refuses
#: (besides private names, methods and every attribute of its :class:`EnvConfig`).
FIXED_ATTRIBUTES = frozenset(
    {
        "config",
        "engine",
        "n_envs",
        "n_agents",
        "num_envs",
        "observation_space",
        "action_space",
        "render_mode",
        "metadata",
        "last_outcome",
        "reset_infos",
    }
)

#: The VecEnv's own argument, before the environment's (:mod:`fxc_env.config.arguments`).
N_ENVS = Argument(
    "n_envs",
    "int",
    REQUIRED,
    help="number of parallel episodes",
    card="number of parallel episodes (``num_envs = n_envs * N`` sub-environments)",
    kind="integer",
    minimum=1,
    card_type="``int``",
)


class ConsensusVecEnv(VecEnv):
    """SB3 ``VecEnv`` over all agents of ``n_envs`` parallel episodes (parameter sharing).

    Sub-environment ``i = episode * N + agent`` is agent ``agent`` of episode ``episode``;
    ``num_envs = n_envs * N``. Every sub-environment has one agent's spaces (those of
    :class:`ConsensusParallelEnv`; flat ``Box`` only):

    | quantity           | shape                       | dtype   |
    |--------------------|-----------------------------|---------|
    | observations       | ``(num_envs, obs_size)``    | ``obs_dtype`` (float64 by default) |
    | actions (accepted) | ``(num_envs, 2 dim)``       | any real, applied as float64 |
    | rewards            | ``(num_envs,)``             | float32 (team reward repeated per agent) |
    | dones              | ``(num_envs,)``             | bool    |

    Episodes share the clock and end together (terminated at ``T_s``, truncated by
    ``max_cycles``) and restart at once (auto-reset, as :class:`DummyVecEnv`); at the end every
    info carries ``terminal_observation``, ``TimeLimit.truncated`` and ``episode_metrics``.
    :meth:`seed` sets ``seed + i`` for sub-environment i and episode b reads that of ``b * N``
    (the episodes of a ``ConsensusParallelEnv`` reset with that seed). :meth:`get_attr`,
    :meth:`set_attr` and :meth:`env_method` act on this one object (:meth:`set_attr` refuses what
    the config fixes); :meth:`render` tiles the first ``min(n_envs, 16)`` episodes. Docs:
    tutorials/sb3.md, "The VecEnv's contract".

    ## Arguments
    ``n_envs`` is positional, every other argument keyword-only; the environment's arguments
    are those of :class:`ConsensusParallelEnv` (``obs_format="flat"`` only). Defaults in
    brackets come from the scenario when one is named.

    {arguments table}
    """

    __doc__ = with_arguments_table(__doc__, (N_ENVS, *ENV_ARGUMENTS, *FRONT_END_ARGUMENTS))

    @env_signature(before=(N_ENVS,), after=FRONT_END_ARGUMENTS)
    def __init__(
        self,
        n_envs: int,
        *,
        scenario: str | None = None,
        render_mode: str | None = None,
        max_cycles: int | None = None,
        **kwargs: Unpack[EnvKwargs],
    ) -> None:
        arguments = env_arguments(locals(), kwargs)
        n_envs = N_ENVS.check(n_envs)
        check_render_mode(render_mode)
        check_max_cycles(max_cycles)
        config = make_config(**arguments)
        if config.obs_format != "flat":
            raise ArgumentError(
                f"obs_format: ConsensusVecEnv supports only obs_format='flat' (a Box per agent), "
                f"got {config.obs_format!r}"
            )
        self.config: EnvConfig = config
        self.n_envs = int(n_envs)
        self.n_agents = config.n_agents
        self.max_cycles = max_cycles
        self.render_mode = render_mode
        self.engine = ConsensusEngine(config, n_episodes=self.n_envs)
        #: What the last step did per episode and agent (``None`` before the first step).
        self.last_outcome: StepOutcome | None = None
        #: One generator per episode, made at the first reset (so copies of a fresh VecEnv differ).
        self._rngs: list[np.random.Generator] | None = None
        self._actions: np.ndarray | None = None
        self._needs_reset = True
        self._steps = 0
        self._view = EpisodeView(config, render_mode, episodes=min(self.n_envs, GRID_EPISODES))
        self._infos_pool: tuple[dict[str, Any], ...] | None = None
        super().__init__(self.n_envs * self.n_agents, observation_space(config), action_space(config))
        self.metadata = dict(ConsensusParallelEnv.metadata)

    # ------------------------------------------------------------ reset/seed
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed sub-environment i with ``seed + i`` at the next :meth:`reset` (random if None)."""
        seed = validation.optional_seed("seed", seed)
        if seed is not None and seed + self.num_envs > validation.MAX_SEED:
            raise ArgumentError(
                f"seed: sub-environment seeds seed + i must stay below 2**128; expected at most "
                f"{validation.MAX_SEED - self.num_envs}, got {seed!r}"
            )
        return super().seed(seed)

    def set_options(self, options: list[dict] | dict | None = None) -> None:
        """Options for the next :meth:`reset` (SB3's form); episode b reads those of sub-env ``b * N``.

        Raises naming ``options`` (or ``options['x0']``, ``options['v0']``) if one that would
        be read is bad; nothing is stored then, and later resets work as before.
        """
        if options is not None and not isinstance(options, dict):
            if not isinstance(options, Sequence) or isinstance(options, str | bytes):
                raise ArgumentTypeError(
                    f"options: expected a dict, a list of dicts or None, got {type(options).__name__}"
                )
            if len(options) != self.num_envs:
                raise ArgumentError(
                    f"options: expected one entry per sub-environment ({self.num_envs}), got {len(options)}"
                )
            for entry in options:  # the keys of every entry, read or not (an unknown key is a typo)
                validation.reset_options("options", entry)
        chosen = [options] if options is None or isinstance(options, dict) else options[:: self.n_agents]
        for entry in chosen:
            if entry:
                initial_state_options(self.engine, entry)
        super().set_options(options)

    def reset(self) -> np.ndarray:
        """Restart every episode; observations ``(num_envs, obs_size)``.

        Consumes the seeds and options set since the last reset (see the class docstring).
        """
        n = self.n_agents
        try:
            overrides = {b: initial_state_options(self.engine, o) for b, o in enumerate(self._options[::n]) if o}
        except ArgumentError:
            self._reset_options()  # bad options are used (refused) once, so later resets work
            raise
        seeds = self._seeds[::n]
        draws = self._draw_episodes(seeds)
        for b, (given_x, given_v) in overrides.items():
            draws[b] = with_initial_state(draws[b], given_x, given_v)
        self._reset_seeds()
        self._reset_options()
        # Noise, dropout and random switching draw from one batch generator, seeded with the
        # first episode's seed (its own stream: (seed, 1)); they make episodes differ from
        # separate ParallelEnv runs, which the initial states alone do not.
        rng = None if seeds[0] is None else np.random.default_rng((seeds[0], 1))
        self._start(draws, rng)
        return self._observe()

    def _draw_episodes(self, seeds: Sequence[int | None] | None = None) -> list[EpisodeDraw]:
        """Each episode's draw (initial state, topology, input limit) from its own generator,
        re-seeded where ``seeds[b]`` is given (:meth:`ConsensusEngine.draw_episode`)."""
        if self._rngs is None:
            self._rngs = [np.random.default_rng(s) for s in np.random.SeedSequence().spawn(self.n_envs)]
        draws = []
        for b in range(self.n_envs):  # the one per-episode loop: independent generators
            if seeds is not None and seeds[b] is not None:
                self._rngs[b] = np.random.default_rng(seeds[b])
            draws.append(self.engine.draw_episode(self._rngs[b]))
        return draws

    def _start(self, draws: Sequence[EpisodeDraw], rng: np.random.Generator | None = None) -> None:
        self.engine.reset_from_draws(draws, rng)
        self._steps = 0
        self._needs_reset = False
        n = self.config.n_agents
        self.reset_infos = [episode_draw_info(draws[i // n]) for i in range(self.num_envs)]
        self._view.start(self.engine)

    def episode_edges(self, episode: int) -> list[list[list[int]]]:
        """Episode ``episode``'s graphs as lists of ``[j, i]`` pairs (:meth:`ConsensusParallelEnv.episode_edges`).

        Sub-environment ``i`` belongs to episode ``i // N``. Not in :attr:`reset_infos` (which
        carry only a drawn ``u_max``): the lists' length changes from draw to draw.
        """
        if self._needs_reset:
            raise RuntimeError("episode_edges: there is no episode yet; call reset() first")
        episode = validation.integer("episode", episode, minimum=0, maximum=self.n_envs - 1)
        return edge_lists(self.engine.topologies[episode])

    def _empty_infos(self) -> list[dict[str, Any]]:
        """One empty dict per sub-environment, reused across steps while they stay empty.

        Building 1e5 fresh dicts every step cost as much as the physics; a consumer that
        writes into one gets fresh dicts from the next step on.
        """
        if self._infos_pool is None or any(self._infos_pool):
            self._infos_pool = tuple({} for _ in range(self.num_envs))
        return list(self._infos_pool)

    def _observe(self) -> np.ndarray:
        return self.engine.observations().reshape(self.num_envs, -1).astype(self.config.observation_dtype, copy=False)

    # ------------------------------------------------------------------ step
    def step_async(self, actions: np.ndarray) -> None:
        """Check and store actions ``(num_envs, 2 dim)``; raise naming ``actions`` if bad."""
        if self._needs_reset:
            raise RuntimeError("step: call reset() before the first step")
        array = np.asarray(actions)
        expected = (self.num_envs, self.config.action_size)
        if array.dtype.kind not in "iuf":  # booleans too: True is no action
            raise ArgumentTypeError(f"actions: expected real numbers, got dtype {array.dtype}")
        if array.shape != expected:
            raise ArgumentError(f"actions: expected shape {expected} (num_envs, 2 dim), got {array.shape}")
        if not np.all(np.isfinite(array)):
            raise ArgumentError("actions: every entry must be finite (no NaN or inf)")
        self._actions = array.astype(np.float64).reshape(self.n_envs, self.n_agents, -1)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Play one interval in every episode; auto-reset all of them when they end."""
        if self._actions is None:
            raise RuntimeError("step_wait: call step_async(actions) first")
        outcome = self.engine.step(self._actions)
        self._actions = None
        self.last_outcome = outcome
        self._steps += 1
        terminated = outcome.terminated
        truncated = not terminated and self.max_cycles is not None and self._steps >= self.max_cycles
        rewards = np.repeat(outcome.reward.astype(np.float32), self.n_agents)
        obs = self._observe()
        if self.render_mode is not None:  # nothing on the step path otherwise
            self._view.record(self.engine)
        if not (terminated or truncated):
            return obs, rewards, np.zeros(self.num_envs, dtype=bool), self._empty_infos()
        per_agent = [episode for episode in episode_metrics_rows(self.engine) for _ in range(self.n_agents)]
        infos = [
            {"terminal_observation": row, "TimeLimit.truncated": truncated, "episode_metrics": dict(episode)}
            for row, episode in zip(obs, per_agent, strict=True)
        ]
        self._start(self._draw_episodes())
        return self._observe(), rewards, np.ones(self.num_envs, dtype=bool), infos

    # ------------------------------------------------------------ attributes
    def _resolve(self, name: str) -> Any:
        if hasattr(self, name):
            return getattr(self, name)
        if hasattr(self.config, name):
            return getattr(self.config, name)
        raise AttributeError(f"attr_name: neither ConsensusVecEnv nor its EnvConfig has an attribute {name!r}")

    def _index_list(self, indices: VecEnvIndices) -> list[int]:
        chosen = list(self._get_indices(indices))
        bad = [i for i in chosen if not -self.num_envs <= i < self.num_envs]
        if bad:
            raise IndexError(f"indices: {bad} out of range for num_envs = {self.num_envs}")
        return chosen

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The shared value of ``attr_name`` (here, else on :attr:`config`), once per index."""
        return [self._resolve(attr_name)] * len(self._index_list(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set ``attr_name`` on the shared environment; ``indices`` must cover every sub-env."""
        if {i % self.num_envs for i in self._index_list(indices)} != set(range(self.num_envs)):
            raise ArgumentError(
                "indices: all sub-environments share one environment, so set_attr applies to all of them; "
                "pass indices=None"
            )
        if not isinstance(attr_name, str):
            raise ArgumentTypeError(f"attr_name: expected a str, got {attr_name!r}")
        if (
            attr_name.startswith("_")
            or attr_name in FIXED_ATTRIBUTES
            or hasattr(self.config, attr_name)
            or callable(getattr(type(self), attr_name, None))
        ):
            raise ArgumentError(
                f"{attr_name}: fixed when the ConsensusVecEnv is built (by its config, its structure or its "
                "methods); build a new ConsensusVecEnv instead"
            )
        if attr_name == "max_cycles":
            check_max_cycles(value)
        setattr(self, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call the shared environment's method once; its result repeated once per index."""
        chosen = self._index_list(indices)
        return [self._resolve(method_name)(*method_args, **method_kwargs)] * len(chosen)

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        """Always False: the sub-environments are no gymnasium envs and carry no wrappers."""
        return [False] * len(self._index_list(indices))

    def state(self) -> np.ndarray:
        """Global states of all episodes: raw ``(n_envs, N, 2 dim)`` rows ``[x_i, v_i]``, or normalized ``(n_envs, N * 2 dim + 3)``.

        One row per episode of what :meth:`ConsensusParallelEnv.state` returns for the same ``global_state``.
        """
        if self.config.global_state == "normalized":
            return normalized_state(self.engine)
        return np.array(self.engine.absolute_state().reshape(self.engine.n_episodes, self.n_agents, -1))

    # ---------------------------------------------------------------- render
    def render(self, mode: str | None = None) -> np.ndarray | None:
        """The first ``min(n_envs, 16)`` episodes so far, tiled: ``(H, W, 3)`` uint8 (``rgb_array``), None (``human``).

        One frame per episode (docs: video.md, "Video"), laid out as Stable-Baselines3's ``tile_images``
        lays out :meth:`get_images` (``ceil(sqrt(n))`` rows), but per episode, not per agent.
        """
        if mode is not None and mode != self.render_mode:
            warnings.warn(f"render: mode {mode!r} differs from render_mode {self.render_mode!r}", stacklevel=2)
            return None
        if self.render_mode is None:
            warnings.warn("render: build the ConsensusVecEnv with render_mode='rgb_array' or 'human'", stacklevel=2)
            return None
        if self._needs_reset:
            raise RuntimeError("render: there is no episode to draw yet; call reset() first")
        return self._view.grid()

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One frame per sub-environment (``rgb_array`` only): its episode's frame so far.

        Sub-environment ``b * N + i`` (agent i of episode b) gets episode b's frame, drawn once
        and shared by the episode's N agents. The first 16 episodes are recorded; the
        sub-environments of later ones share one blank frame that says so. Other render modes
        warn and give None per sub-environment, as SB3's ``DummyVecEnv`` does.
        """
        if self.render_mode != "rgb_array":
            warnings.warn(
                f"get_images: needs render_mode='rgb_array', the ConsensusVecEnv has {self.render_mode!r}", stacklevel=2
            )
            return [None] * self.num_envs
        if self._needs_reset:
            raise RuntimeError("get_images: there is no episode to draw yet; call reset() first")
        frames = self._view.frames()
        if self.n_envs > len(frames):
            frames.append(
                blank_frame(f"episodes {len(frames)}-{self.n_envs - 1} are not recorded (the first {len(frames)} are)")
            )
        return [frames[min(b, len(frames) - 1)] for b in range(self.n_envs) for _ in range(self.n_agents)]

    def close(self) -> None:
        self._view.close()
