"""One way to call a policy, and ``rollout``, which plays one episode of the parallel env with it (``seeded_metrics``: seeded episodes on the engine).

Every policy the project ships or loads (the paper's controller ``fxc_env.ReferencePolicy``, every law of
``fxc_env.baselines``, every learned format ``fxc_env.policies.learned.load_learned_policy`` reads,
with a memory or without) is called the same way:

- ``policy(observations)`` with the parallel env's dict ``{agent: observation}`` returns ``{agent: action}``;
  the agents act as one batch, stacked in the dict's order (the env's agent order, which a law with a
  memory or a per-agent plan relies on);
- ``policy(array)`` with every agent's observation ``(..., N, obs_size)`` returns ``(..., N, action_size)``;
- ``policy(observation)`` with one agent's observation ``(obs_size,)`` (flat, or a dict observation of
  ``obs_format="dict"``) returns its action ``(action_size,)``: the per-agent (AEC-style) call. Only a policy
  without memory can answer it; a policy that keeps a memory per agent, or plans per agent from every
  agent's observation, refuses it by name (``Policy.needs_team``): called agent by agent, one memory
  would run through every agent's rows;
- ``policy.reset()`` forgets the memory of the episodes under way (a no-op where there is none).

Whether a mapping is the team's ``{agent: observation}`` or one agent's dict observation (keys among
``neighbours``, ``mask``, ``clock``, ``input_limit``: ``OBSERVATION_KEYS``) is decided here and
nowhere else (``team_observations``). Docs: getting-started.md, "One policy protocol".
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np

from fxc_env.config.layout import ObservationLayout
from fxc_env.core import validation
from fxc_env.core.validation import ArgumentError
from fxc_env.engine import ConsensusEngine

#: The keys of one agent's dict observation (``obs_format="dict"``; ``input_limit`` only with ``u_max``).
OBSERVATION_KEYS = frozenset({"neighbours", "mask", "clock", "input_limit"})


def team_observations(observation: Any) -> dict[Any, Any] | None:
    """``observation`` as ``{agent: observation}`` when it maps agents to observations (the parallel env's), else None.

    A mapping whose keys all name parts of one agent's dict observation (``OBSERVATION_KEYS``) is that
    agent's observation, not a team; any other mapping is read as the team's.
    """
    if not isinstance(observation, Mapping):
        return None
    return None if observation and set(observation) <= OBSERVATION_KEYS else dict(observation)


def flat_observation(observation: Any) -> np.ndarray:
    """A flat observation ``(..., obs_size)`` from a flat one or one agent's dict one (``obs_format="dict"``).

    The dict's ``neighbours`` ``(..., slots, row)``, ``mask``, ``clock`` and ``input_limit`` (when present) in the
    flat layout's order (``fxc_env.config.layout.ObservationLayout.flat``); anything else as an array.
    """
    if not isinstance(observation, Mapping):
        return np.asarray(observation)
    missing = [key for key in ("neighbours", "mask", "clock") if key not in observation]
    if missing:
        raise ArgumentError(
            f"observations: a dict observation needs 'neighbours', 'mask' and 'clock' (obs_format='dict'); "
            f"missing {missing}"
        )
    return ObservationLayout(1, 1, limit_feature="input_limit" in observation).flat(observation)


def needs_team(policy: Any) -> bool:
    """Whether ``policy``, or a policy it wraps (``.policy``), acts only for the whole team at once.

    True for a policy with a memory per agent or a per-agent plan (``Policy.needs_team``).
    """
    while policy is not None:
        if getattr(policy, "needs_team", False):
            return True
        policy = getattr(policy, "policy", None)
    return False


def reset_policy(policy: Any) -> None:
    """``policy.reset()`` where it has one (a plain function has no memory to forget)."""
    reset = getattr(policy, "reset", None)
    if callable(reset):
        reset()


def policy_name(policy: Any) -> str:
    """How messages name ``policy``: its class, its law's ``NAME`` and the file it was read from, where known."""
    name = type(policy).__name__
    law = getattr(type(policy), "NAME", None)
    source = getattr(policy, "source", None)
    return name + (f" ({law})" if law else "") + (f" from {source}" if source else "")


def refuse_one_agent(policy: Any, obs_size: Any) -> None:
    """Raise ``ArgumentError`` naming ``observations`` and ``policy``: it is called with one agent's observation."""
    raise ArgumentError(
        f"observations: {policy_name(policy)} acts for every agent at once (it keeps a memory per agent or plans "
        f"per agent); call it with the parallel env's whole dict, policy(observations) -> {{agent: action}}, or "
        f"an array (..., N, {obs_size}), not agent by agent with one agent's observation (AEC style)"
    )


def call_policy(policy: Any, observation: Any, act: Callable[[Any], Any], convert: bool = True) -> Any:
    """The protocol (see the module): ``act`` maps flat observations ``(..., obs_size)`` to actions.

    A team dict is stacked ``(N, obs_size)`` in its order and answered ``{agent: action}``; one agent's
    observation is refused by name when ``needs_team(policy)``. ``convert``: flat observations as float64
    numpy (False passes arrays and tensors through as given).
    """
    agents = team_observations(observation)
    if agents is not None:
        if not agents:
            return {}
        rows = [np.asarray(flat_observation(obs), dtype=np.float64) for obs in agents.values()]
        if len({row.shape for row in rows}) > 1:
            shapes = {agent: row.shape for agent, row in zip(agents, rows, strict=True)}
            raise ArgumentError(f"observations: every agent's observation must have one shape, got {shapes}")
        return dict(zip(agents, act(np.stack(rows)), strict=True))
    obs = flat_observation(observation) if isinstance(observation, Mapping) else observation
    obs = np.asarray(obs, dtype=np.float64) if convert or not hasattr(obs, "shape") else obs
    if needs_team(policy) and obs.ndim < 2:
        refuse_one_agent(policy, obs.shape[-1] if obs.ndim else "obs_size")
    return act(obs)


class Policy:
    """Base class of the project's policies: the call of the module, on ``act``.

    Subclasses implement ``act`` (flat float64 observations ``(..., obs_size)`` to actions
    ``(..., action_size)``), set ``needs_team`` when they keep a memory per agent or plan per agent, and
    override ``reset`` when they have a memory.
    """

    #: Acts only for every agent at once (a memory per agent, or a per-agent plan): one agent's observation
    #: alone is refused by name.
    needs_team: ClassVar[bool] = False

    def __call__(self, observations: Any) -> Any:
        """``{agent: action}`` for the parallel env's ``{agent: observation}``; actions ``(..., action_size)`` for
        observations ``(..., obs_size)`` (flat or one agent's dict observation)."""
        return call_policy(self, observations, self.act)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for flat observations ``(..., obs_size)``."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the memory of the episodes under way (none here)."""


def rollout(env: Any, policy: Any, seed: int | None = None, *, trajectory: bool = False) -> Any:
    """Play one episode of the parallel env with ``policy`` called as ``policy(observations)``.

    Calls ``policy.reset()`` (where it has one), ``env.reset(seed=seed)``, then ``env.step(policy(observations))``
    until the episode ends.

    Args:
        env: a PettingZoo parallel env (``fxc_env.parallel_env(...)``).
        policy: a policy on the env's dict ``{agent: observation}`` (every policy of the project; see the module).
        seed: the episode's seed (None or an integer in ``[0, 2**128)``), as ``env.reset``.
        trajectory: also return the episode's steps.

    Returns:
        The episode's infos: what the env reports at the end (``infos[agent]["episode"]``, the fields of
        ``fxc_env.core.metrics.EpisodeMetrics``). With ``trajectory=True``, ``(episode, steps)``: ``steps``
        maps ``observations`` ``(K, N, obs_size)`` (flat, as the policy saw them at each step), ``actions``
        ``(K, N, action_size)`` and ``rewards`` ``(K, N)``, float64, agents in ``env.possible_agents`` order.

    Refuses by name (``ArgumentError``) an ``env`` that is not a parallel env, a ``policy`` that cannot be called,
    a bad ``seed`` or ``trajectory``, before anything is reset.
    """
    from pettingzoo import ParallelEnv

    if not isinstance(env, ParallelEnv):
        raise ArgumentError(
            f"env: expected a PettingZoo parallel env (fxc_env.parallel_env(...)), got {type(env).__name__} "
            "(the AEC env fxc_env.env(...) plays agent by agent: use its parallel form)"
        )
    if not callable(policy):
        raise ArgumentError(f"policy: expected a policy called as policy(observations), got {type(policy).__name__}")
    seed = validation.optional_seed("seed", seed)
    validation.boolean("trajectory", trajectory)
    reset_policy(policy)
    observations, infos = env.reset(seed=seed)
    agents = list(env.possible_agents)
    steps: dict[str, list[np.ndarray]] = {"observations": [], "actions": [], "rewards": []}
    while env.agents:
        actions = policy(observations)
        if trajectory:
            steps["observations"].append(np.stack([flat_observation(observations[a]) for a in agents]))
            steps["actions"].append(np.stack([np.asarray(actions[a]) for a in agents]))
        observations, rewards, _, _, infos = env.step(actions)
        if trajectory:
            steps["rewards"].append(np.array([rewards[a] for a in agents]))
    episode = dict(infos[agents[0]].get("episode", {}))
    if not trajectory:
        return episode
    return episode, {key: np.asarray(value, dtype=np.float64) for key, value in steps.items()}


def seeded_engine(config: Any, seeds: Any, rng: Any = None) -> tuple[ConsensusEngine, list[Any]]:
    """An engine of ``config`` playing one episode per seed (episode b drawn from ``np.random.default_rng(seeds[b])``;
    noise, dropout and random switching from ``rng``), reset, and the episodes' draws."""
    engine = ConsensusEngine(config, n_episodes=len(seeds))
    draws = [engine.draw_episode(np.random.default_rng(seed)) for seed in seeds]
    engine.reset_from_draws(draws, rng)
    return engine, draws


def seeded_metrics(config: Any, policy: Any, seeds: Any, rng: Any = None) -> dict[str, np.ndarray]:
    """Every agent of the :func:`seeded_engine` episodes acting by ``policy(observations (B, N, obs_size))`` to the
    end; the engine's episode metrics, one ``(B,)`` array each."""
    engine, _ = seeded_engine(config, seeds, rng)
    while not engine.done:
        engine.step(np.asarray(policy(np.asarray(engine.observations())), dtype=np.float64))
    return engine.batch_metrics()
