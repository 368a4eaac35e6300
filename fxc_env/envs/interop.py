"""fxc_env inside other RL libraries' PettingZoo wrappers: TorchRL.

:class:`FlatEpisodeInfos` gives TorchRL's :class:`~torchrl.envs.libs.pettingzoo.PettingZooWrapper`,
which stores every info entry as a tensor, one flat schema: the step keys plus
``episode_<metric>`` for each metric of the nested ``episode`` dict, NaN until the step that ends
the episode. RLlib's PettingZoo wrapper lives with the RLlib trainer
(``fxc_env.training.backends.rllib_train``). For TorchRL at speed use
:class:`fxc_env.envs.torch_env.ConsensusTorchEnv` (docs: performance.md, "Performance").
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any

import numpy as np
from pettingzoo import ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper

from fxc_env.core.metrics import EpisodeMetrics
from fxc_env.core.validation import ArgumentError
from fxc_env.envs.fxc_consensus_v0 import parallel_env

#: Prefix of the flat episode-metric keys (``episode_relative_deadline_error``, ...).
EPISODE_PREFIX = "episode_"
#: The flat keys, one per field of :class:`fxc_env.core.metrics.EpisodeMetrics`.
EPISODE_KEYS = tuple(EPISODE_PREFIX + f.name for f in fields(EpisodeMetrics))


def flat_info(info: dict[str, Any]) -> dict[str, Any]:
    """``info`` with its ``episode`` dict spread into float64 ``episode_<metric>`` keys (NaN if absent)."""
    flat = {key: value for key, value in info.items() if key != "episode"}
    episode = info.get("episode") or {}  # numbers only; a None (older metric dicts) reads as NaN
    for key in EPISODE_KEYS:
        value = episode.get(key.removeprefix(EPISODE_PREFIX))
        flat[key] = np.float64(math.nan if value is None else value)
    return flat


class FlatEpisodeInfos(BaseParallelWrapper):
    """A parallel fxc_env whose infos have the same flat numeric keys at reset and at every step."""

    def __init__(self, env: ParallelEnv) -> None:
        super().__init__(env)
        self.metadata = env.metadata

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        observations, infos = self.env.reset(seed=seed, options=options)
        return observations, {agent: flat_info(info) for agent, info in infos.items()}

    def step(self, actions: dict[str, Any]):
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        return observations, rewards, terminations, truncations, {a: flat_info(i) for a, i in infos.items()}


def torchrl_wrapper(group: str = "agents", **kwargs: Any) -> Any:
    """A TorchRL env of ``fxc_env.parallel_env(**kwargs)``: every agent in one group, infos flat.

    Needs ``pip install "fxc-env[torchrl]"``. Continuous actions, no agent mask (agents
    never leave before the episode end), the global state under ``"state"`` (``(N, 2 dim)``
    float64, or ``(N * 2 dim + 3,)`` with ``global_state="normalized"``). Data of the group
    lie under ``(group, "observation" | "action" | "reward" | "info")`` with a leading agent
    dimension N. With ``obs_dtype="float32"`` observations (and the normalized state) are
    float32 tensors, ready for a float32 policy; actions may be float32 or float64.
    """
    try:
        from torchrl.envs.libs.pettingzoo import PettingZooWrapper
    except ModuleNotFoundError as exc:
        raise ArgumentError('torchrl_wrapper: TorchRL is not installed; pip install "fxc-env[torchrl]"') from exc
    env = FlatEpisodeInfos(parallel_env(**kwargs))
    return PettingZooWrapper(
        env, group_map={group: list(env.possible_agents)}, categorical_actions=False, use_mask=False, return_state=True
    )
