"""One episode on random digraphs from N = 10^2 to 10^6: seconds per sampling interval, per agent-step, memory.

Per N, an interval is the reference (paper eq. 11) as users run it, :meth:`ReferencePolicy.step
<fxc_env.policies.reference.ReferencePolicy.step>`: on these exact observations the whole interval
in one pass of the compiled kernel (:mod:`fxc_env.engine.reference`; no observations built); the
peak memory is traced while building and stepping. The goals: one interval at N = :data:`INTERVAL_GOAL_N` (``dim = 1``) within
:data:`INTERVAL_GOAL` seconds and within :data:`PRODUCT_GOAL` times a bare scipy CSR product on the
same graph, measured in the same run (:func:`interval_and_product`), and ``dim = 2`` within
:data:`RATIO_GOAL` times ``dim = 1`` at N = :data:`RATIO_N`.
"""

from __future__ import annotations

import time
import tracemalloc
from typing import Any

import numpy as np
import scipy.sparse as sp

from fxc_env.config import make_config
from fxc_env.engine import ConsensusEngine, reference
from fxc_env.policies.reference import ReferencePolicy
from fxc_env.speed.timing import alternate, met, timed_rate

#: The first N of the scaling table; ``--largest`` is at least this.
SCALING_FIRST_N = 100


#: The scaling table's dimensions: the paper's ``dim = 1``, then the plane and space.
SCALING_DIMS = (1, 2, 3)

#: N at which the table compares each ``dim`` with ``dim = 1``, and the goal for ``dim = 2``.
RATIO_N = 100_000

RATIO_GOAL = 3.0

#: The engine's interval goal: seconds per interval at N = INTERVAL_GOAL_N (random digraph, mean in-degree 4, dim = 1).
INTERVAL_GOAL_N = 10**6
INTERVAL_GOAL = 0.1
#: The same interval within this many times one bare scipy CSR product (:func:`interval_and_product`).
PRODUCT_GOAL = 1.2
#: Alternating rounds, and intervals (and products) per round, of :func:`interval_and_product`.
PRODUCT_ROUNDS, PRODUCT_STEPS = 7, 3


def scaling_row(n_agents: int, steps: int, dim: int = 1, **model: Any) -> tuple[float, float, float]:
    """(seconds per interval, seconds per agent-step, peak traced MiB) for one episode in ``dim`` dimensions.

    ``model``: ``agent_model`` and its parameters (default: the double integrator's closed forms).
    """
    tracemalloc.start()
    config = make_config(
        topology="random", n_agents=n_agents, mean_in_degree=4.0, n_intervals=steps + 1, dim=dim, **model
    )
    engine = ConsensusEngine(config, n_episodes=1)
    x0, v0 = engine.sample_initial_state(np.random.default_rng(0))
    engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(config)
    policy.step(engine)  # warm-up
    start = time.perf_counter()
    for _ in range(steps):
        policy.step(engine)
    seconds = (time.perf_counter() - start) / steps
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return seconds, seconds / n_agents, peak / 2**20


def scaling_table(largest: int, dims: tuple[int, ...] = (1,)) -> list[str]:
    """One table of N = 100, 1000, ... up to ``largest`` per ``dim`` (each headed when ``dims`` has several).

    With ``dim = 1`` among several, closing lines give each other dim's time per interval
    over ``dim = 1``'s at N = :data:`RATIO_N` (at the largest N measured when ``largest``
    is smaller, saying so), and ``dim = 2``'s against :data:`RATIO_GOAL`. With ``dim = 1``,
    the last line is the interval goal at N = :data:`INTERVAL_GOAL_N` (:func:`interval_goal_line`).
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
        n = SCALING_FIRST_N
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
    if 1 in dims:
        measured_product = INTERVAL_GOAL_N in measured
        lines += ["", product_goal_line(*interval_and_product(INTERVAL_GOAL_N) if measured_product else (None, None))]
        lines.append(interval_goal_line(seconds_at.get((1, INTERVAL_GOAL_N))))
    return lines


def interval_and_product(
    n_agents: int, rounds: int = PRODUCT_ROUNDS, steps: int = PRODUCT_STEPS
) -> tuple[float, float]:
    """Median seconds of one interval and of one bare scipy CSR product on the same graph, alternated.

    The interval is :func:`scaling_row`'s (``ReferencePolicy.step``: the plan from the neighbour
    sums, the exact step with its inputs, energy, peak, disagreement and reward; random digraph
    of mean in-degree 4, ``dim = 1``), without tracemalloc. The product is the graph's Laplacian ``L`` (scipy CSR, ``N x N``, one entry per
    edge and one per agent, int32 indices) times the state ``[x v]`` ``(N, 2)``: the neighbour
    sums ``sum_j (x_j - x_i)`` and ``sum_j (v_j - v_i)`` of the paper's plan (eq. 11) and nothing
    else. Each round times ``steps`` intervals, then ``steps`` products; medians over ``rounds``.
    """
    config = make_config(topology="random", n_agents=n_agents, mean_in_degree=4.0, n_intervals=(rounds + 1) * steps + 1)
    engine = ConsensusEngine(config, n_episodes=1)
    x0, v0 = engine.sample_initial_state(np.random.default_rng(0))
    engine.reset(x0[None], v0[None])
    policy = ReferencePolicy(config)
    laplacian = config.topology.laplacian()
    laplacian = sp.csr_array(
        (laplacian.data, laplacian.indices.astype(np.int32), laplacian.indptr.astype(np.int32)), shape=laplacian.shape
    )
    state = engine.state[0].reshape(n_agents, 2).copy()

    def interval() -> None:
        policy.step(engine)

    def product() -> None:
        laplacian @ state

    interval(), product()  # warm-up: the engine's block buffers, the product's output pages
    rates = alternate(
        {"interval": lambda: timed_rate(interval, steps), "product": lambda: timed_rate(product, steps)}, rounds
    )
    return 1.0 / rates["interval"], 1.0 / rates["product"]


def product_goal_line(seconds_per_interval: float | None, seconds_per_product: float | None) -> str:
    """The line comparing one interval at N = :data:`INTERVAL_GOAL_N` with a bare CSR product (None: not measured)."""
    path = "compiled kernel" if reference.KERNEL is not None else "observations: the compiled kernel was not built"
    where = f"one reference interval ({path}) / one scipy CSR product (Laplacian x [x v]) at N={INTERVAL_GOAL_N:,}"
    goal = f"goal <= {PRODUCT_GOAL:g}x"
    if seconds_per_interval is None or seconds_per_product is None:
        return f"{where}: not measured ({goal}: pass --largest {INTERVAL_GOAL_N})"
    ratio = seconds_per_interval / seconds_per_product
    return (
        f"{where}: {ratio:.2f}x ({seconds_per_interval * 1e3:.1f} ms / {seconds_per_product * 1e3:.1f} ms) "
        f"({goal}: {met(ratio <= PRODUCT_GOAL)})"
    )


def interval_goal_line(seconds_per_interval: float | None) -> str:
    """The interval goal's line from the ``dim = 1`` time at N = :data:`INTERVAL_GOAL_N` (None: not measured)."""
    where = f"one interval at N={INTERVAL_GOAL_N:,} (random digraph, mean in-degree 4, dim = 1, reference policy)"
    goal = f"goal <= {INTERVAL_GOAL:g} s"
    if seconds_per_interval is None:
        return f"{where}: not measured ({goal}: pass --largest {INTERVAL_GOAL_N})"
    ratio = seconds_per_interval / INTERVAL_GOAL
    return (
        f"{where}: {seconds_per_interval:.3f} s, {ratio:.2f}x the goal "
        f"({goal}: {met(seconds_per_interval <= INTERVAL_GOAL)})"
    )
