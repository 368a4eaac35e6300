"""Agent models: time per agent-step of every model in one episode, against the double integrator's closed forms."""

from __future__ import annotations

from fxc_env.core.linear import model_matrices
from fxc_env.speed.scaling import scaling_row
from fxc_env.speed.timing import met

#: Agents of the agent-model table, and its goal: the general path within 10x the closed forms per agent-step.
MODELS_N = 100_000
MODELS_GOAL = 10.0
#: Intervals timed per agent model.
MODELS_STEPS = 20


def models_table(n_agents: int | None = None, steps: int | None = None) -> list[str]:
    """Time per agent-step of every agent model in one episode (random digraph, dim = 1).

    ``n_agents`` agents (default :data:`MODELS_N`), ``steps`` intervals timed (default :data:`MODELS_STEPS`).

    The double integrator twice: by its closed forms, and as ``(A, B)`` through the general
    path (matrix exponentials and the scaled Gramian, :mod:`fxc_env.core.linear`), whose ratio
    is the goal line.
    """
    n_agents = MODELS_N if n_agents is None else n_agents
    steps = MODELS_STEPS if steps is None else steps
    models = [
        ("double_integrator (closed forms)", {}),
        ("double_integrator as (A, B) (general path)", {"agent_model": model_matrices("double_integrator")}),
        ("single_integrator", {"agent_model": "single_integrator"}),
        ("integrator_chain, order 3", {"agent_model": {"name": "integrator_chain", "order": 3}}),
        ("integrator_chain, order 4", {"agent_model": {"name": "integrator_chain", "order": 4}}),
        ("damped", {"agent_model": "damped"}),
        ("oscillator", {"agent_model": "oscillator"}),
    ]
    lines = ["| agent model | ns / agent-step | vs closed forms |", "|---|---:|---:|"]
    per_agent = {}
    for name, model in models:
        per_agent[name] = scaling_row(n_agents, steps, 1, **model)[1]
        ratio = per_agent[name] / per_agent[models[0][0]]
        lines.append(f"| {name} | {per_agent[name] * 1e9:.0f} | {ratio:.1f}x |")
    general = per_agent[models[1][0]] / per_agent[models[0][0]]
    lines += [
        "",
        f"general path / closed forms at N={n_agents:,}: {general:.1f}x (goal <= {MODELS_GOAL:g}x: {met(general <= MODELS_GOAL)})",
    ]
    return lines
