"""The graph-agnostic law's goal table (docs: optimality.md, "Exact consensus without knowing the graph").

``python -c "from fxc_env.baselines.harness.graph_agnostic_goals import goal_table; print(goal_table())"`` prints it:
uniform K = 200, T_s = 20 s, raw plans, medians over 20 seeded initial states, ``max_agents = N`` and ``2N``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fxc_env.baselines.registry import LAWS
from fxc_env.core.validation import ArgumentError

__all__ = ["goal_row", "goal_table", "strongly_connected_random"]


def strongly_connected_random(n_agents: int, mean_in_degree: float) -> tuple[Any, int]:
    """The first ``random`` digraph (topology seed 0, 1, …) of N agents that is strongly connected, and its seed."""
    from scipy.sparse import csgraph

    from fxc_env.core.graphs import random_topology

    for seed in range(10_000):
        topology = random_topology(n_agents, seed=seed, mean_in_degree=mean_in_degree)
        if csgraph.connected_components(topology.adjacency(0), directed=True, connection="strong")[0] == 1:
            return topology, seed
    raise ArgumentError(f"mean_in_degree: no strongly connected random digraph of {n_agents} agents in 10,000 seeds")


def goal_row(settings: dict[str, Any], max_factor: int, seeds: range) -> tuple[float, float] | str:
    """Median relative deadline error and energy / E* of the law on seeded episodes, or its refusal."""
    from fxc_env.config import make_config
    from fxc_env.policies.protocol import seeded_metrics

    config = make_config(**settings)
    try:
        policy = LAWS["graph_agnostic"].policy(config, max_agents=max_factor * config.n_agents)
    except ArgumentError as exc:
        return f"refused: {str(exc).split(':')[0]}"
    metrics = seeded_metrics(config, policy, seeds)
    return float(np.median(metrics["relative_deadline_error"])), float(np.median(metrics["energy_ratio"]))


def goal_table(n_seeds: int = 20) -> str:
    """The goal table (docs: optimality.md, "Exact consensus without knowing the graph"): K = 200, T_s = 20 s, raw plans, medians over ``n_seeds`` seeded initial states."""
    common = {"n_intervals": 200, "settling_time": 20.0, "action_mode": "plan", "obs_mode": "raw"}
    uniform = {**common, "scenario": None, "schedule": "uniform"}
    random_20, seed_20 = strongly_connected_random(20, 2.0)
    random_40, seed_40 = strongly_connected_random(40, 3.0)
    cases = [
        ("directed ring N = 20", {**uniform, "topology": "ring", "n_agents": 20}),
        ("directed ring N = 30", {**uniform, "topology": "ring", "n_agents": 30}),
        (f"random strongly connected N = 20 (in-degree 2, seed {seed_20})", {**uniform, "topology": random_20}),
        (f"random strongly connected N = 40 (in-degree 3, seed {seed_40})", {**uniform, "topology": random_40}),
        ("directed ring N = 20, paper schedule", {**common, "scenario": None, "topology": "ring", "n_agents": 20}),
        ("paper_fig1 (periodic switching)", {**common, "scenario": "paper_fig1", "schedule": "uniform"}),
    ]
    lines = [
        "| case | max_agents = N: error, energy / E* | max_agents = 2N: error, energy / E* |",
        "|---|---|---|",
    ]
    for label, settings in cases:
        cells = []
        for factor in (1, 2):
            row = goal_row(settings, factor, range(n_seeds))
            cells.append(row if isinstance(row, str) else f"{row[0]:.1e}, {row[1]:.3g}")
        lines.append(f"| {label} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines)
