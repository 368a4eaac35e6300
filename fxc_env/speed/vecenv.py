"""``ConsensusVecEnv`` against VMAS on the CPU: agent-steps per second at the same total agent count.

Our SB3 VecEnv (``paper_fig1``, N = 6 per environment) driven by the reference policy, against
VMAS ``navigation`` and ``simple_spread`` (6 agents per environment, random actions).
"""

from __future__ import annotations

from collections.abc import Callable

from fxc_env.speed.timing import alternate, timed_rate


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


def vmas_stepper(
    scenario: str, total_agents: int, seed: int = 0, device: str = "cpu"
) -> tuple[Callable[[], None], int]:
    """One step of a VMAS scenario on ``device`` (6 agents per env) with random actions."""
    import torch
    import vmas

    n_envs = -(-total_agents // 6)
    env = vmas.make_env(scenario, num_envs=n_envs, device=device, continuous_actions=True, seed=seed, n_agents=6)
    env.reset()
    generator = torch.Generator().manual_seed(seed)
    actions = [
        [
            (2 * torch.rand((n_envs, env.get_agent_action_size(agent)), generator=generator) - 1).to(device)
            for agent in env.agents
        ]
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
