"""ParallelEnv against MPE2: env-steps per second through PettingZoo's dict API, random actions.

Our :class:`~fxc_env.envs.parallel.ConsensusParallelEnv` (``paper_fig1`` at N = 6, a random
digraph at N = 20) against MPE2 ``simple_spread_v3`` with continuous actions and the same
N, both stepped by :func:`random_action_stepper` (64 pre-drawn joint actions, resets
included). The goal: at N = 6, at least :data:`PARALLEL_GOAL` times MPE2's env-steps/s.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from fxc_env.speed.timing import BLOCK_SECONDS, alternate, calibrated_count, met, timed_rate

#: N of the table's rows.
PARALLEL_SIZES = (6, 20)
#: The goal: our env-steps/s over MPE2's at N = PARALLEL_GOAL_N.
PARALLEL_GOAL = 20.0
PARALLEL_GOAL_N = 6


def parallel_env_stepper(n_agents: int, seed: int = 0) -> Callable[[], None]:
    """One step of our ParallelEnv with pre-drawn random actions (reset at episode end)."""
    import fxc_env

    kwargs: dict[str, Any] = (
        {"scenario": "paper_fig1"} if n_agents == 6 else {"topology": "random", "n_agents": n_agents}
    )
    return random_action_stepper(fxc_env.parallel_env(**kwargs), seed)


def random_action_stepper(env: Any, seed: int) -> Callable[[], None]:
    """One step of a PettingZoo parallel env with 64 pre-drawn random joint actions, reset at the end.

    The same harness for every contender, so the comparison times the environments alone.
    """
    env.reset(seed=seed)
    agents = list(env.possible_agents)
    space = env.action_space(agents[0])
    space.seed(seed)
    actions = [{agent: space.sample() for agent in agents} for _ in range(64)]
    counter = iter(range(10**12))

    def step() -> None:
        env.step(actions[next(counter) % 64])
        if not env.agents:
            env.reset()

    return step


def mpe2_stepper(n_agents: int, seed: int = 0) -> Callable[[], None]:
    """One step of MPE2 ``simple_spread_v3`` (continuous actions) with pre-drawn random actions."""
    from mpe2 import simple_spread_v3

    env = simple_spread_v3.parallel_env(N=n_agents, continuous_actions=True, max_cycles=200)
    return random_action_stepper(env, seed)


def parallel_rates(
    rounds: int, sizes: Sequence[int] = PARALLEL_SIZES, seconds: float = BLOCK_SECONDS
) -> dict[tuple[str, int], float]:
    """Env-steps per second keyed by ``("ours" | "mpe2", N)``, the two alternated round by round at each N."""
    rates: dict[tuple[str, int], float] = {}
    for n in sizes:
        contenders = {}
        for name, stepper in (("ours", parallel_env_stepper), ("mpe2", mpe2_stepper)):
            step = stepper(n)
            count = calibrated_count(step, seconds, most=10**6)
            contenders[name] = lambda s=step, c=count: timed_rate(s, c)
        for name, rate in alternate(contenders, rounds).items():
            rates[name, n] = rate
    return rates


def parallel_table(rounds: int, sizes: Sequence[int] = PARALLEL_SIZES, seconds: float = BLOCK_SECONDS) -> list[str]:
    """The table (one row per N) and the goal line at N = :data:`PARALLEL_GOAL_N` (when measured)."""
    rates = parallel_rates(rounds, sizes, seconds)
    lines = [
        "| N | fxc_env ParallelEnv (env-steps/s) | MPE2 simple_spread_v3 (env-steps/s) | ratio |",
        "|---|---:|---:|---:|",
    ]
    for n in sizes:
        ours, theirs = rates["ours", n], rates["mpe2", n]
        lines.append(f"| {n} | {ours:,.0f} | {theirs:,.0f} | {ours / theirs:.1f}x |")
    if PARALLEL_GOAL_N in sizes:
        ratio = rates["ours", PARALLEL_GOAL_N] / rates["mpe2", PARALLEL_GOAL_N]
        lines += [
            "",
            f"ParallelEnv / MPE2 simple_spread_v3 at N={PARALLEL_GOAL_N}, env-steps/s: {ratio:.1f}x "
            f"(goal >= {PARALLEL_GOAL:g}x: {met(ratio >= PARALLEL_GOAL)})",
        ]
    return lines
