"""The PettingZoo AEC environment: agents act in turn over one :class:`ConsensusParallelEnv`.

Written for this environment instead of PettingZoo's generic ``parallel_to_aec`` so that each
agent's action is checked when that agent acts: a bad action raises at once, naming the
agent, and is not stored, so the same agent can act again.
"""

from __future__ import annotations

from typing import Any, Unpack

import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle
from pettingzoo import AECEnv

from fxc_env.config import EnvConfig
from fxc_env.config.arguments import FRONT_END_ARGUMENTS, GRAPH_TENSORS, EnvKwargs, env_arguments, env_signature
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.parallel import ConsensusParallelEnv

_AEC_PREAMBLE = """Fixed-time consensus of double integrators, AEC form (agents act in turn).

    One sampling interval is one cycle: ``agent_0``, ``agent_1``, ... act in order; each
    action is checked when it is given (a bad one raises :class:`ArgumentError` naming
    ``action of agent_i`` and is not stored: the same agent acts again), and the last agent's
    action plays the interval for all of them. ``rewards`` then hold the team reward,
    ``_cumulative_rewards`` what each agent earned since it last acted (``last()`` returns
    it). At the episode end every agent is terminated (or truncated) and is removed by one
    ``step(None)`` each, as PettingZoo's AEC API asks. Observations, ``state()``, infos,
    spaces, rendering and every argument are those of the parallel form, which this class
    drives (:attr:`parallel`); its card follows.
    """


class ConsensusAECEnv(AECEnv, EzPickle):
    __doc__ = _AEC_PREAMBLE + (ConsensusParallelEnv.__doc__ or "").split("\n", 1)[1]

    metadata = ConsensusParallelEnv.metadata

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
        front = {"render_mode": render_mode, "max_cycles": max_cycles, "graph_tensors": graph_tensors}
        arguments = {**env_arguments(locals(), kwargs), **front}  # the parallel env's arguments, checked there
        AECEnv.__init__(self)
        #: The parallel environment that plays each interval once every agent has acted.
        self.parallel = ConsensusParallelEnv(**arguments)
        EzPickle.__init__(self, **arguments)
        self.render_mode = render_mode
        for name in ("possible_agents", "observation_spaces", "action_spaces", "state_space"):
            setattr(self, name, getattr(self.parallel, name))
        self.agents: list[str] = []
        self.rewards: dict[str, float] = {}
        self._cumulative_rewards: dict[str, float] = {}
        self.terminations: dict[str, bool] = {}
        self.truncations: dict[str, bool] = {}
        self.infos: dict[str, dict[str, Any]] = {}
        self._observations: dict[str, Any] = {}
        self._actions: dict[str, np.ndarray] = {}
        self._turn = 0

    @property
    def config(self) -> EnvConfig:
        """The validated settings (shared with :attr:`parallel`)."""
        return self.parallel.config

    @property
    def max_cycles(self) -> int | None:
        return self.parallel.max_cycles

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self.action_spaces[agent]

    # ---------------------------------------------------------------- pickle
    def __getstate__(self) -> dict[str, Any]:
        return self.__dict__.copy()  # the whole state, as ConsensusParallelEnv

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # ----------------------------------------------------------------- reset
    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> None:
        observations, infos = self.parallel.reset(seed=seed, options=options)  # checks before changing anything
        self.agents = self.parallel.agents[:]
        self._observations = observations
        self.infos = infos
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self._actions = {}
        self._turn = 0
        self._skip_agent_selection = None
        self.agent_selection = self.agents[0]

    def last(self, observe: bool = True) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """PettingZoo's ``last()``; before the first ``reset`` a ``RuntimeError`` (there is no agent to select yet)."""
        if not self._observations:
            raise RuntimeError("last: call reset() first")
        return super().last(observe)

    def observe(self, agent: str) -> Any:
        """``agent``'s latest observation (its last one after the episode end)."""
        if agent not in self._observations:
            if agent in self.possible_agents:
                raise RuntimeError("observe: call reset() first")
            raise ArgumentError(f"agent: unknown agent {agent!r}; expected one of {self.possible_agents}")
        return self._observations[agent]

    # ------------------------------------------------------------------ step
    def step(self, action: Any) -> None:
        """Give the action of :attr:`agent_selection`; the last agent's action plays the interval."""
        if not self.agents:
            raise RuntimeError("step: the episode has ended (or reset() was never called); call reset() first")
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            if action is not None:
                raise ArgumentError(f"action of {agent}: its episode has ended, so the only valid action is None")
            self._was_dead_step(action)
            return
        self._actions[agent] = self.parallel.check_action(agent, action, name=f"action of {agent}")
        if self._turn < len(self.agents) - 1:
            if self._turn == 0:
                self._clear_rewards()  # the previous interval's rewards were seen by everyone
            self._cumulative_rewards[agent] = 0.0
            self._turn += 1
            self.agent_selection = self.agents[self._turn]
            return
        try:
            observations, rewards, terminations, truncations, infos = self.parallel.step(self._actions)
        except Exception:
            del self._actions[agent]  # refused (overflow): the agent acts again, nothing else changed
            raise
        self._cumulative_rewards[agent] = 0.0
        self._actions = {}
        self._observations = observations
        self.rewards = dict(rewards)
        self.terminations = dict(terminations)
        self.truncations = dict(truncations)
        self.infos = infos
        self._accumulate_rewards()
        self._turn = 0
        self.agent_selection = self.agents[0]
        self._deads_step_first()

    def episode_edges(self) -> list[list[list[int]]]:
        """The episode's graphs as lists of ``[j, i]`` pairs (:meth:`ConsensusParallelEnv.episode_edges`)."""
        return self.parallel.episode_edges()

    # ----------------------------------------------------------------- state
    def state(self) -> np.ndarray:
        """The global state of the parallel form (raw or normalized, see ``global_state``)."""
        return self.parallel.state()

    def render(self) -> np.ndarray | None:
        return self.parallel.render()

    def close(self) -> None:
        self.parallel.close()
