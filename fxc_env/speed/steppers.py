"""The engine's own loop (observations -> reference policy -> step), shared by the TorchRL and CUDA tables."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from fxc_env.engine import ConsensusEngine
from fxc_env.policies.reference import ReferencePolicy


def engine_stepper(config: Any, n_episodes: int, device: Any = None, seed: int = 0) -> tuple[Callable[[], None], Any]:
    """One interval of B episodes: ``engine.observations`` -> ``ReferencePolicy.act`` -> ``engine.step``.

    ``device`` None is numpy (observations written into one buffer, as the VecEnv does),
    else a torch device. Episodes restart together (``draw_batch`` + ``reset``) at ``T_s``.
    Returns the step and the engine (for :meth:`~fxc_env.engine.ConsensusEngine.raise_if_invalid`).
    """
    engine = ConsensusEngine(config, n_episodes, device=device)
    engine.seed(seed)
    policy = ReferencePolicy(config)
    host_rng = np.random.default_rng(seed)

    def restart() -> None:
        x0, v0, u_max, topologies = engine.draw_batch(host_rng)
        engine.reset(x0, v0, topologies=topologies, u_max=u_max)

    restart()
    buffer = np.empty((n_episodes, config.n_agents, config.layout.size)) if engine.is_numpy else None

    def step() -> None:
        engine.step(policy.act(engine.observations(buffer)))
        if engine.done:
            restart()

    return step, engine
