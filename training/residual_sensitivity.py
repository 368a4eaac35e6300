"""How much PPO's exploration costs on the rings task: D(T_s)/D(0) under Gaussian residuals around eq. (11).

Directed rings of 20 (a new labelling per episode), K = 200 on the paper's schedule, T_s = 20 s,
``action_mode="residual"``: every agent adds ``sigma * N(0, 1)`` to its correction's ``alpha_x``, its
``alpha_v`` or both, on every interval or on the last / all but the last ``n``. Prints the median
over 20 seeded episodes (docs: results.md, "PPO from scratch around the reference")::

    .venv/bin/python -m fxc_env.training.residual_sensitivity

A velocity correction is applied as ``a_v = s alpha_v / T_s`` and D weighs velocities by ``T_s``,
so noise on ``alpha_v`` moves D by about ``s sigma`` on every interval, as noise on ``alpha_x``
does. (Applied like the plan's ``s alpha_v / T_k``, it moved D by ``s sigma (pi k)^2 / 6``, up to
6.6e4 ``s sigma`` on the last interval: sigma = 1e-3 on ``alpha_v`` alone gave 0.76.)"""

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
