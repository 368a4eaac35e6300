"""How much PPO's exploration costs on the rings task: D(T_s)/D(0) under Gaussian residuals around eq. (11).

Directed rings of 20, K = 200 on the paper's schedule, ``action_mode="residual"``: every agent adds
``sigma * N(0, 1)`` to ``alpha_x``, ``alpha_v`` or both, on every interval or on the last / all but the last
``n``; prints the median over 20 seeded episodes (``.venv/bin/python -m fxc_env.training.recipes.residual_sensitivity``).
"""

from __future__ import annotations

import numpy as np

from fxc_env import make_config
from fxc_env.engine import ConsensusEngine

EPISODES = 20


def median_ratio(sigma: float, parts: slice = slice(None), first: int = 0, stop: int = 200, seed: int = 0) -> float:
    """Median ``D(T_s)/D(0)`` with residual noise ``sigma`` on action ``parts`` over intervals ``[first, stop)``."""
    config = make_config(
        None,
        n_agents=20,
        topology={"family": "ring"},
        initial_state="random",
        obs_slots=1,
        action_mode="residual",
        position_range=5.0,
        velocity_range=2.0,
    )
    engine = ConsensusEngine(config, EPISODES)
    rng = np.random.default_rng(seed)
    engine.reset_from_draws([engine.draw_episode(rng) for _ in range(EPISODES)])
    for k in range(config.n_intervals):
        actions = np.zeros((EPISODES, 20, 2))
        if first <= k < stop:
            actions[..., parts] = sigma * rng.standard_normal((EPISODES, 20, 2))[..., parts]
        engine.step(actions)
    return float(np.median(engine.current_disagreement / engine.initial_disagreement))


def main() -> None:
    print("sigma | both | alpha_x only | alpha_v only")
    for sigma in (0.0, 1e-6, 1e-4, 1e-3, 1e-2, 0.05, 0.2, 1.0):
        row = [median_ratio(sigma), median_ratio(sigma, slice(0, 1)), median_ratio(sigma, slice(1, 2))]
        print(f"{sigma:g} | " + " | ".join(f"{value:.3g}" for value in row))
    print("sigma = 0.05 on both, n | last n intervals only | all but the last n")
    for n in (1, 10, 50, 150):
        print(f"{n} | {median_ratio(0.05, first=200 - n):.3g} | {median_ratio(0.05, stop=200 - n):.3g}")


if __name__ == "__main__":
    main()
