"""``fxc speed``: throughput measured side by side with the environments users would otherwise pick.

Three tables, all from one run on one machine, contenders alternated round by round so
that both see the same machine state; each figure is the median over rounds:

1. our PettingZoo ParallelEnv against MPE2 ``simple_spread_v3`` (continuous actions) at
   N = 6 and N = 20, in env-steps per second through the dict API, random actions;
2. our SB3 ``ConsensusVecEnv`` driven by the reference policy against VMAS on the CPU
   (``navigation`` and ``simple_spread``, random actions) at the same total agent count
   (>= 1e5), in agent-steps per second;
3. one episode on ``random`` digraphs (mean in-degree 4) from N = 10^2 to 10^6, for
   ``dim`` = 1, 2 and 3: seconds per sampling interval (observation + reference policy +
   exact step), per agent-step, and the peak memory traced while building and stepping;
   then the time per interval at ``dim`` = 2 and 3 over that at ``dim`` = 1, at N = 10^5
   (the goal: ``dim`` = 2 within 3x).

Threads are pinned to one (``OMP_NUM_THREADS`` and friends are set before numpy or torch
start, by re-running the command; ``torch.set_num_threads(1)``). MPE2 and VMAS come from
the optional extra ``bench``: ``.venv/bin/pip install -c constraints.txt -e ".[bench]"``.
"""

from __future__ import annotations

import os
import platform
import statistics
import sys
import time
import tracemalloc
from collections.abc import Callable
from typing import Any

import numpy as np

from fxc_env.threads import THREAD_VARIABLES

BENCH_HINT = 'install the optional extra: .venv/bin/pip install -c constraints.txt -e ".[bench]"'


def machine_description() -> str:
    """CPU model, core count, Python and library versions."""
    model = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import torch

    return (
        f"{model}, {os.cpu_count()} cores, {platform.system()} {platform.machine()}, Python {platform.python_version()}, "
        f"numpy {np.__version__}, torch {torch.__version__} (threads: {torch.get_num_threads()})"
    )


def alternate(contenders: dict[str, Callable[[], float]], rounds: int) -> dict[str, float]:
    """Run each contender's timed block once per round, in turn; median rate per contender."""
    rates: dict[str, list[float]] = {name: [] for name in contenders}
    for _ in range(rounds):
        for name, run in contenders.items():
            rates[name].append(run())
    return {name: statistics.median(values) for name, values in rates.items()}


def timed_rate(step: Callable[[], None], count: int) -> float:
    """Calls of ``step`` per second over ``count`` calls."""
    start = time.perf_counter()
    for _ in range(count):
        step()
    return count / (time.perf_counter() - start)


# ------------------------------------------------------------------ ParallelEnv vs MPE2
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


def parallel_table(rounds: int) -> list[str]:
    lines = [
        "| N | fxc_env ParallelEnv (env-steps/s) | MPE2 simple_spread_v3 (env-steps/s) | ratio |",
        "|---|---:|---:|---:|",
    ]
    for n in (6, 20):
        ours, theirs = parallel_env_stepper(n), mpe2_stepper(n)
        ours_count, theirs_count = 4000, 400 if n == 6 else 60
        rates = alternate(
            {
                "ours": lambda s=ours, c=ours_count: timed_rate(s, c),
                "mpe2": lambda s=theirs, c=theirs_count: timed_rate(s, c),
            },
            rounds,
        )
        lines.append(f"| {n} | {rates['ours']:,.0f} | {rates['mpe2']:,.0f} | {rates['ours'] / rates['mpe2']:.1f}x |")
    return lines


# ---------------------------------------------------------------- VecEnv vs VMAS
def vec_env_stepper(total_agents: int, seed: int = 0) -> tuple[Callable[[], None], int]:
    """One step of ``ConsensusVecEnv`` (paper_fig1, N = 6) driven by the reference policy."""
    import fxc_env

    n_envs = -(-total_agents // 6)
    venv = fxc_env.ConsensusVecEnv(n_envs, scenario="paper_fig1")
    venv.seed(seed)
    policy = fxc_env.ReferencePolicy(venv)
    state = {"obs": venv.reset()}

    def step() -> None:
        obs, _, _, _ = venv.step(policy(state["obs"]))
        state["obs"] = obs

    return step, venv.num_envs


def vmas_stepper(scenario: str, total_agents: int, seed: int = 0) -> tuple[Callable[[], None], int]:
    """One step of a VMAS scenario on the CPU (6 agents per env) with random actions."""
    import torch
    import vmas

    n_envs = -(-total_agents // 6)
    env = vmas.make_env(scenario, num_envs=n_envs, device="cpu", continuous_actions=True, seed=seed, n_agents=6)
    env.reset()
    generator = torch.Generator().manual_seed(seed)
    actions = [
        [2 * torch.rand((n_envs, env.get_agent_action_size(agent)), generator=generator) - 1 for agent in env.agents]
        for _ in range(8)
    ]
    counter = iter(range(10**12))

    def step() -> None:
        env.step(actions[next(counter) % 8])

    return step, n_envs * len(env.agents)


def vec_table(total_agents: int, rounds: int) -> list[str]:
    ours, ours_agents = vec_env_stepper(total_agents)
    contenders = {"ours": lambda: timed_rate(ours, 20) * ours_agents}
    sizes = {"ours": ours_agents}
    for scenario in ("navigation", "simple_spread"):
        step, agents = vmas_stepper(scenario, total_agents)
        contenders[scenario] = lambda s=step, a=agents: timed_rate(s, 3) * a
        sizes[scenario] = agents
    rates = alternate(contenders, rounds)
    lines = [
        "| contender | agents | agent-steps/s | fxc_env ratio |",
        "|---|---:|---:|---:|",
        f"| fxc_env ConsensusVecEnv + ReferencePolicy (paper_fig1) | {sizes['ours']:,} | {rates['ours']:,.0f} | 1.0x |",
    ]
    for scenario in ("navigation", "simple_spread"):
        lines.append(
            f"| VMAS {scenario} (CPU, random actions) | {sizes[scenario]:,} | {rates[scenario]:,.0f} | "
            f"{rates['ours'] / rates[scenario]:.1f}x |"
        )
    return lines


# ----------------------------------------------------------------- scaling table
#: The scaling table's dimensions: the paper's ``dim = 1``, then the plane and space.
SCALING_DIMS = (1, 2, 3)
#: N at which the table compares each ``dim`` with ``dim = 1``, and the goal for ``dim = 2``.
RATIO_N = 100_000
RATIO_GOAL = 3.0


def scaling_row(n_agents: int, steps: int, dim: int = 1) -> tuple[float, float, float]:
    """(seconds per interval, seconds per agent-step, peak traced MiB) for one episode in ``dim`` dimensions."""
    from fxc_env.config import make_config
    from fxc_env.engine import ConsensusEngine
    from fxc_env.reference import ReferencePolicy

    tracemalloc.start()
    config = make_config(topology="random", n_agents=n_agents, mean_in_degree=4.0, n_intervals=steps + 1, dim=dim)
    engine = ConsensusEngine(config, n_episodes=1)
    x0, v0 = engine.sample_initial_state(np.random.default_rng(0))
    engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(config)
    buffer = np.empty((1, n_agents, config.layout.size))
    engine.step(policy(engine.observations(buffer)))  # warm-up
    start = time.perf_counter()
    for _ in range(steps):
        engine.step(policy(engine.observations(buffer)))
    seconds = (time.perf_counter() - start) / steps
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return seconds, seconds / n_agents, peak / 2**20


def scaling_table(largest: int, dims: tuple[int, ...] = (1,)) -> list[str]:
    """One table of N = 100, 1000, ... up to ``largest`` per ``dim`` (each headed when ``dims`` has several).

    With ``dim = 1`` among several, closing lines give each other dim's time per interval
    over ``dim = 1``'s at N = :data:`RATIO_N` (at the largest N measured when ``largest``
    is smaller, saying so), and ``dim = 2``'s against :data:`RATIO_GOAL`.
    """
    lines: list[str] = []
    seconds_at: dict[tuple[int, int], float] = {}
    for dim in dims:
        if len(dims) > 1:
            lines += ([""] if lines else []) + [f"dim = {dim}:", ""]
        lines += [
            "| N | seconds / interval | ns / agent-step | peak traced memory (MiB) |",
            "|---:|---:|---:|---:|",
        ]
        n = 100
        while n <= largest:
            steps = int(min(200, max(5, 2e6 / n)))
            seconds, per_agent, peak = scaling_row(n, steps, dim)
            seconds_at[dim, n] = seconds
            lines.append(f"| {n:,} | {seconds:.2e} | {per_agent * 1e9:.0f} | {peak:,.1f} |")
            n *= 10
    measured = sorted(n for d, n in seconds_at if d == 1)
    if len(dims) > 1 and measured:
        compared = RATIO_N if RATIO_N in measured else measured[-1]
        lines.append("")
        for dim in dims:
            if dim == 1 or (dim, compared) not in seconds_at:
                continue
            ratio = seconds_at[dim, compared] / seconds_at[1, compared]
            goal = f" (goal <= {RATIO_GOAL:g}x)" if dim == 2 else ""
            lines.append(f"dim={dim} / dim=1 at N={compared:,}: {ratio:.1f}x{goal}")
        if compared != RATIO_N:
            lines.append(f"(the goal is stated at N={RATIO_N:,}: pass --largest {RATIO_N} or more)")
    return lines


def run(args: Any) -> int:
    """Print the three tables (``args``: ``rounds``, ``total_agents``, ``largest``, ``skip``)."""
    import torch

    torch.set_num_threads(1)
    print("# fxc speed")
    print(f"machine: {machine_description()}")
    print("threads: " + ", ".join(f"{name}={os.environ.get(name)}" for name in THREAD_VARIABLES) + ", torch 1")
    print(f"rounds per contender: {args.rounds} (alternating; median reported)")
    missing = [name for name in ("mpe2", "vmas") if not _importable(name)]
    if missing and not args.skip_contenders:
        print(f"fxc speed: {', '.join(missing)} missing; {BENCH_HINT} (or pass --skip-contenders)", file=sys.stderr)
        return 2
    if not args.skip_contenders:
        print("\n## ParallelEnv vs MPE2 (dict API, random actions, resets included)\n")
        print("\n".join(parallel_table(args.rounds)))
        print(f"\n## ConsensusVecEnv vs VMAS on CPU (>= {args.total_agents:,} agents, one thread)\n")
        print("\n".join(vec_table(args.total_agents, args.rounds)))
    print("\n## One episode on random digraphs (mean in-degree 4), reference policy, dim = 1, 2, 3\n")
    print("\n".join(scaling_table(args.largest, SCALING_DIMS)))
    return 0


def _importable(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None
