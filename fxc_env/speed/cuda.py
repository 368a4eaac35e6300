"""The GPU tables (``--device cuda``): the engine and the reference on torch CUDA, VMAS and JaxMARL beside it.

The engine (float64, ``dim = 1``) from 1e4 to 1e8 agents (N = 1000 random digraphs and N = 6
``paper_fig1``, B episodes each; a size that does not fit in the GPU's memory is skipped with
a note), single episodes of N = 1e6 and 1e7 (ms per interval), and, where importable, VMAS
``simple_spread`` (torch CUDA) and JaxMARL ``MPE_simple_spread_v3`` (``jit`` + ``vmap``) at
262,144 environments, alternated with the engine round by round.
"""

from __future__ import annotations

import gc
import os
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

from fxc_env.config import make_config
from fxc_env.speed.steppers import engine_stepper
from fxc_env.speed.timing import BLOCK_SECONDS, alternate, calibrated_count, importable, met, timed_rate
from fxc_env.speed.vecenv import vmas_stepper

#: B x N of the CUDA sweep, and its two episode sizes: N = 1000 (random digraphs) and N = 6 (paper_fig1).
CUDA_SIZES = (10**4, 10**5, 10**6, 10**7, 10**8)

CUDA_EPISODE_SIZES = (1000, 6)

#: N of the single-episode rows and the goal (ms per interval) of each.
CUDA_SINGLE = {10**6: 2.0, 10**7: 20.0}

#: The engine's goal on CUDA: agent-steps/s at >= CUDA_RATE_AT agents.
CUDA_RATE_GOAL = 2e9

CUDA_RATE_AT = 10**6

#: Environments of the CUDA comparison (6 agents each).
CUDA_COMPARE_ENVS = 262_144

OURS_ON_GPU = "fxc_env engine + ReferencePolicy (paper_fig1, float64)"

#: JaxMARL steps per jitted call (one ``lax.scan``; its episodes last 25 steps).
JAX_STEPS_PER_CALL = 25


def synchronizer(device: Any) -> Callable[[], None] | None:
    """``torch.cuda.synchronize`` for a CUDA device, else None (nothing to wait for)."""
    import torch

    return (lambda: torch.cuda.synchronize(device)) if torch.device(device).type == "cuda" else None


def release_memory(device: Any) -> None:
    """Drop what the last measurement left: Python's cycles, then torch's cached CUDA blocks."""
    import torch

    gc.collect()
    if torch.device(device).type == "cuda":
        torch.cuda.empty_cache()


def out_of_memory(error: BaseException) -> bool:
    """Whether ``error`` says the device (or the host) ran out of memory, as torch, cuBLAS or Python say it."""
    import torch

    text = str(error)
    return isinstance(error, torch.OutOfMemoryError | MemoryError) or "out of memory" in text or "ALLOC_FAILED" in text


def device_engine_rate(config: Any, n_episodes: int, device: Any, rounds: int, seconds: float) -> float | None:
    """Intervals per second of B episodes on ``device`` (median of ``rounds`` synchronised blocks), None when out of memory."""
    try:
        step, engine = engine_stepper(config, n_episodes, device=device)
        sync = synchronizer(device)
        count = calibrated_count(step, seconds, sync)
        rate = statistics.median(timed_rate(step, count, sync) for _ in range(rounds))
        engine.raise_if_invalid()
        return rate
    except (MemoryError, RuntimeError) as error:  # torch.OutOfMemoryError is a RuntimeError
        if not out_of_memory(error):
            raise
        return None
    finally:
        step = engine = None
        release_memory(device)


def _episode_config(n_agents: int) -> Any:
    if n_agents == 6:
        return make_config(scenario="paper_fig1")
    return make_config(topology="random", n_agents=n_agents, mean_in_degree=4.0, dim=1)


def cuda_sweep_table(
    device: Any,
    rounds: int,
    sizes: Sequence[int] = CUDA_SIZES,
    episode_sizes: Sequence[int] = CUDA_EPISODE_SIZES,
    seconds: float = BLOCK_SECONDS,
) -> tuple[list[str], dict[tuple[int, int], float]]:
    """Engine + reference at B x N agents on ``device``: the table and ``{(N, B x N): agent-steps/s}``.

    Each size runs alone (the largest do not fit beside each other), median over ``rounds``.
    """
    lines = [
        "| episode | N | episodes B | agents B×N | ms / step | agent-steps/s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    rates: dict[tuple[int, int], float] = {}
    for n in episode_sizes:
        config = _episode_config(n)
        name = "paper_fig1" if n == 6 else "random, in-degree 4"
        for size in sizes:
            b = max(1, -(-size // n))
            rate = device_engine_rate(config, b, device, rounds, seconds)
            if rate is None:
                lines.append(f"| {name} | {n:,} | {b:,} | {b * n:,} | out of memory: skipped | |")
                continue
            rates[n, b * n] = rate * b * n
            lines.append(f"| {name} | {n:,} | {b:,} | {b * n:,} | {1e3 / rate:.3f} | {rate * b * n:,.0f} |")
    return lines, rates


def cuda_single_table(
    device: Any, rounds: int, sizes: Sequence[int] = tuple(CUDA_SINGLE), seconds: float = BLOCK_SECONDS
) -> tuple[list[str], dict[int, float]]:
    """One episode of N agents (random digraph, mean in-degree 4) on ``device``: the table and ``{N: ms per interval}``."""
    lines = [
        "| N | graph built on the host (s) | ms / interval | agent-steps/s |",
        "|---:|---:|---:|---:|",
    ]
    result: dict[int, float] = {}
    for n in sizes:
        start = time.perf_counter()
        config = _episode_config(n)
        built = time.perf_counter() - start
        rate = device_engine_rate(config, 1, device, rounds, seconds)
        if rate is None:
            lines.append(f"| {n:,} | {built:.1f} | out of memory: skipped | |")
            continue
        result[n] = 1e3 / rate
        lines.append(f"| {n:,} | {built:.1f} | {1e3 / rate:.3f} | {rate * n:,.0f} |")
        config = None
        release_memory(device)
    return lines, result


def jaxmarl_stepper(n_envs: int, n_agents: int = 6, seed: int = 0, steps_per_call: int = 25) -> tuple[Any, Any]:
    """``steps_per_call`` steps of JaxMARL ``MPE_simple_spread_v3`` (continuous, random actions) per call.

    ``jax.jit`` over ``jax.lax.scan`` of ``jax.vmap(env.step)`` (auto-reset included), the
    observations and rewards summed into the carry so that XLA computes them. Returns the
    call and its sync (``block_until_ready`` on the carry).
    """
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # share the GPU with torch
    import jax
    import jax.numpy as jnp
    import jaxmarl

    if jax.default_backend() not in ("gpu", "cuda", "rocm"):
        raise RuntimeError(f"jax runs on {jax.default_backend()!r}, not on the GPU (install jax with CUDA)")
    env = jaxmarl.make("MPE_simple_spread_v3", num_agents=n_agents, num_landmarks=n_agents, action_type="Continuous")
    agents = list(env.agents)
    shapes = {agent: tuple(env.action_space(agent).shape) for agent in agents}
    step = jax.vmap(env.step)

    def one(carry: Any, _: Any) -> tuple[Any, None]:
        key, state, checksum = carry
        key, action_key, step_key = jax.random.split(key, 3)
        action_keys = jax.random.split(action_key, len(agents))
        actions = {a: jax.random.uniform(k, (n_envs, *shapes[a])) for a, k in zip(agents, action_keys, strict=True)}
        obs, state, rewards, _, _ = step(jax.random.split(step_key, n_envs), state, actions)
        checksum = checksum + sum(jnp.sum(obs[a]) + jnp.sum(rewards[a]) for a in agents)
        return (key, state, checksum), None

    @jax.jit
    def run(carry: Any) -> Any:
        return jax.lax.scan(one, carry, None, length=steps_per_call)[0]

    key, reset_key = jax.random.split(jax.random.PRNGKey(seed))
    _, state = jax.jit(jax.vmap(env.reset))(jax.random.split(reset_key, n_envs))
    holder = {"carry": (key, state, jnp.zeros(()))}

    def call() -> None:
        holder["carry"] = run(holder["carry"])

    return call, lambda: jax.block_until_ready(holder["carry"])


def cuda_compare_table(
    device: Any, rounds: int, n_envs: int = CUDA_COMPARE_ENVS, contenders: bool = True, seconds: float = BLOCK_SECONDS
) -> list[str]:
    """Engine + reference (paper_fig1) against VMAS and JaxMARL ``simple_spread`` at ``n_envs`` x 6 agents on the GPU.

    A contender that is not importable here, or fails to start (out of memory, no GPU
    backend), is named in a note under the table instead of a row.
    """
    agents = n_envs * 6
    timed: dict[str, Callable[[], float]] = {}
    notes: list[str] = []

    def add(name: str, step: Callable[[], None], steps_per_call: int, sync: Callable[[], None] | None) -> None:
        count = calibrated_count(step, seconds, sync)
        timed[name] = lambda: timed_rate(step, count, sync) * steps_per_call * agents

    try:
        add(
            OURS_ON_GPU,
            engine_stepper(make_config(scenario="paper_fig1"), n_envs, device=device)[0],
            1,
            synchronizer(device),
        )
    except (MemoryError, RuntimeError) as error:
        if not out_of_memory(error):
            raise
        notes.append(f"fxc_env engine: out of memory at {agents:,} agents")
    if contenders:
        _add_contenders(add, notes, device, agents, n_envs)
    rates = alternate(timed, rounds) if timed else {}
    ours = rates.get(OURS_ON_GPU)
    lines = [
        "| contender | environments | agents | agent-steps/s | fxc_env ratio |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, rate in rates.items():
        ratio = f"{ours / rate:.1f}x" if ours is not None else ""
        lines.append(f"| {name} | {n_envs:,} | {agents:,} | {rate:,.0f} | {ratio} |")
    return lines + (["", *notes] if notes else [])


def _add_contenders(add: Callable[..., None], notes: list[str], device: Any, agents: int, n_envs: int) -> None:
    """VMAS and JaxMARL ``simple_spread`` through ``add`` where they start; a note naming why otherwise."""
    if importable("vmas"):
        try:
            step = vmas_stepper("simple_spread", agents, device=str(device))[0]
            add(f"VMAS simple_spread (torch on {device}, float32, random actions)", step, 1, synchronizer(device))
        except Exception as error:  # an optional contender that fails to start is reported, not fatal
            notes.append(f"VMAS simple_spread: skipped ({type(error).__name__}: {error})".splitlines()[0])
    else:
        notes.append("VMAS: not importable here (pip install vmas)")
    if importable("jaxmarl") and importable("jax"):
        try:
            call, sync = jaxmarl_stepper(n_envs, steps_per_call=JAX_STEPS_PER_CALL)
            add(
                "JaxMARL MPE_simple_spread_v3 (jit + vmap + scan, float32, random actions)",
                call,
                JAX_STEPS_PER_CALL,
                sync,
            )
        except Exception as error:  # as above: jax without CUDA, clashing CUDA libraries, out of memory, ...
            notes.append(f"JaxMARL MPE_simple_spread_v3: skipped ({type(error).__name__}: {error})".splitlines()[0])
    else:
        notes.append("JaxMARL: not importable here (pip install jaxmarl, jax with CUDA)")


def cuda_tables(
    device: Any,
    rounds: int,
    contenders: bool = True,
    sizes: Sequence[int] = CUDA_SIZES,
    episode_sizes: Sequence[int] = CUDA_EPISODE_SIZES,
    single: Sequence[int] = tuple(CUDA_SINGLE),
    compare_envs: int = CUDA_COMPARE_ENVS,
    seconds: float = BLOCK_SECONDS,
    out: Callable[[str], None] = print,
) -> None:
    """Print the CUDA tables (each as soon as it is measured) and their goal lines."""
    out(f"\n## Engine + reference on {device_description(device)} (float64, dim = 1), B episodes of N agents\n")
    lines, rates = cuda_sweep_table(device, rounds, sizes, episode_sizes, seconds)
    out("\n".join(lines))
    large = {key: rate for key, rate in rates.items() if key[1] >= CUDA_RATE_AT}
    if large:
        (n, agents), best = max(large.items(), key=lambda item: item[1])
        out(
            f"\nengine + reference, best at >= {CUDA_RATE_AT:,} agents: {best:,.0f} agent-steps/s "
            f"(N = {n:,}, {agents:,} agents) (goal >= {CUDA_RATE_GOAL:,.0f}: {met(best >= CUDA_RATE_GOAL)})"
        )
    else:
        out(
            f"\nno size of >= {CUDA_RATE_AT:,} agents was measured (goal >= {CUDA_RATE_GOAL:,.0f} agent-steps/s: not met)"
        )
    out(f"\n## One episode on a random digraph (mean in-degree 4), engine + reference on {device}\n")
    lines, intervals = cuda_single_table(device, rounds, single, seconds)
    out("\n".join(lines))
    goals = [
        f"N={n:,}: {intervals[n]:.3f} ms (goal <= {CUDA_SINGLE[n]:g} ms: {met(intervals[n] <= CUDA_SINGLE[n])})"
        for n in single
        if n in intervals and n in CUDA_SINGLE
    ]
    if goals:
        out("\n" + "; ".join(goals))
    out(
        f"\n## On {device} against VMAS and JaxMARL simple_spread ({compare_envs:,} environments, 6 agents each, "
        "alternating)\n"
    )
    out("\n".join(cuda_compare_table(device, rounds, compare_envs, contenders, seconds)))


def device_description(device: Any) -> str:
    """``cuda:0 (NVIDIA H100 ..., 80 GiB)`` for a CUDA device, else the device's name."""
    import torch

    chosen = torch.device(device)
    if chosen.type != "cuda":
        return str(chosen)
    properties = torch.cuda.get_device_properties(chosen)
    return f"{chosen} ({properties.name}, {properties.total_memory / 2**30:.0f} GiB, torch CUDA {torch.version.cuda})"
