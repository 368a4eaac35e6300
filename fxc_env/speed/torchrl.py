"""TorchRL on the CPU: the PettingZoo wrapper, :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv` and the engine.

At N = 6 (``paper_fig1``), agent-steps per second of the environment in TorchRL's
``PettingZooWrapper`` (one episode), of the native batched ``ConsensusTorchEnv`` (``env.step``
+ ``step_mdp``, ``reference_policy(env)``) at B x N of about 6e3 and 1e5 agents, and of the
batched engine alone on torch and on numpy at the same sizes. The goals: ``ConsensusTorchEnv``
>= :data:`TORCHRL_WRAPPER_GOAL` times the wrapper at 6e3 agents, and >= :data:`TORCHRL_NUMPY_GOAL`
of the numpy engine at 1e5 agents.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import Any

from fxc_env.config import make_config
from fxc_env.speed.steppers import engine_stepper
from fxc_env.speed.timing import BLOCK_SECONDS, alternate, calibrated_count, met, timed_rate

#: B x N of the TorchRL table's two batch sizes (about; B is rounded up to whole episodes of 6).
TORCHRL_SIZES = (6_000, 100_000)

#: The TorchRL table's goals: ConsensusTorchEnv over the PettingZoo wrapper at the small size,
#: and over the numpy engine at the large one.
TORCHRL_WRAPPER_GOAL = 1000.0

TORCHRL_NUMPY_GOAL = 0.5


def _stepper(env: Any, policy: Any) -> Callable[[], None]:
    """``env.step`` of ``policy``'s actions and ``step_mdp``; ``env.reset()`` once the episodes are done."""
    from torchrl.envs.utils import step_mdp

    state = {"td": env.reset()}

    def step() -> None:
        td = step_mdp(env.step(policy(state["td"])))
        state["td"] = env.reset() if bool(td["done"].any()) else td

    return step


def torchrl_wrapper_stepper(seed: int = 0) -> Callable[[], None]:
    """One env-step of ``paper_fig1`` in TorchRL's ``PettingZooWrapper`` (:func:`fxc_env.envs.interop.torchrl_wrapper`).

    The reference policy as a ``TensorDictModule`` on the group's observations, then
    ``env.step`` and ``step_mdp``; ``env.reset()`` when the episode is done.
    """
    from tensordict.nn import TensorDictModule

    from fxc_env.envs.interop import torchrl_wrapper
    from fxc_env.policies.torchrl_reference import ReferenceModule

    with warnings.catch_warnings():  # TorchRL warns about the PettingZoo version it was tested with
        warnings.simplefilter("ignore")
        env = torchrl_wrapper(scenario="paper_fig1")
    env.set_seed(seed)
    policy = TensorDictModule(
        ReferenceModule(make_config(scenario="paper_fig1")),
        in_keys=[("agents", "observation")],
        out_keys=[("agents", "action")],
    )
    return _stepper(env, policy)


def torchrl_batched_stepper(n_episodes: int, seed: int = 0, device: str = "cpu") -> Callable[[], None]:
    """One step of :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv` (``paper_fig1``, B episodes).

    What a TorchRL user writes: ``reference_policy(env)``, ``env.step``, ``step_mdp``, and
    ``env.reset()`` once the episodes are done.
    """
    from fxc_env.envs.torch_env import ConsensusTorchEnv
    from fxc_env.policies.torchrl_reference import reference_policy

    env = ConsensusTorchEnv(batch_size=n_episodes, device=device, seed=seed, scenario="paper_fig1")
    return _stepper(env, reference_policy(env))


#: The TorchRL table's rows: (key, label) per contender at each size.
TORCHRL_ROWS = (
    ("torchrl_env", "ConsensusTorchEnv + reference_policy (env.step + step_mdp)"),
    ("torch_engine", "ConsensusEngine on torch (CPU) + ReferencePolicy"),
    ("numpy_engine", "ConsensusEngine on numpy + ReferencePolicy"),
)

WRAPPER_LABEL = "TorchRL PettingZooWrapper(parallel_env) + reference (one episode)"


def torchrl_rates(
    rounds: int, sizes: Sequence[int] = TORCHRL_SIZES, seconds: float = BLOCK_SECONDS
) -> dict[tuple[str, int], float]:
    """Agent-steps per second, keyed by ``(contender, agents)``, all alternated round by round.

    ``("wrapper", 6)`` is the PettingZoo wrapper; each size in ``sizes`` (B x N, rounded up
    to whole ``paper_fig1`` episodes) has the keys of :data:`TORCHRL_ROWS`.
    """
    config = make_config(scenario="paper_fig1")
    n = config.n_agents
    steppers: dict[tuple[str, int], tuple[Callable[[], None], int]] = {("wrapper", n): (torchrl_wrapper_stepper(), n)}
    for size in sizes:
        b = -(-size // n)
        steppers["torchrl_env", b * n] = (torchrl_batched_stepper(b), b * n)
        steppers["torch_engine", b * n] = (engine_stepper(config, b, device="cpu")[0], b * n)
        steppers["numpy_engine", b * n] = (engine_stepper(config, b)[0], b * n)
    contenders = {}
    for key, (step, agents) in steppers.items():
        count = calibrated_count(step, seconds)
        contenders[key] = lambda s=step, c=count, a=agents: timed_rate(s, c) * a
    return alternate(contenders, rounds)


def torchrl_table(rounds: int, sizes: Sequence[int] = TORCHRL_SIZES, seconds: float = BLOCK_SECONDS) -> list[str]:
    """The TorchRL table (see the module docstring) and its goal lines."""
    rates = torchrl_rates(rounds, sizes, seconds)
    wrapper = rates["wrapper", 6]
    lines = [
        "| contender | episodes B | agents B×N | agent-steps/s | vs PettingZoo wrapper | vs numpy engine |",
        "|---|---:|---:|---:|---:|---:|",
        f"| {WRAPPER_LABEL} | 1 | 6 | {wrapper:,.0f} | 1x | |",
    ]
    agent_counts = sorted({agents for key, agents in rates if key != "wrapper"})
    for agents in agent_counts:
        numpy_rate = rates["numpy_engine", agents]
        for key, label in TORCHRL_ROWS:
            rate = rates[key, agents]
            lines.append(
                f"| {label} | {agents // 6:,} | {agents:,} | {rate:,.0f} | {rate / wrapper:,.0f}x | "
                f"{rate / numpy_rate:.0%} |"
            )
    small, large = agent_counts[0], agent_counts[-1]
    over_wrapper = rates["torchrl_env", small] / wrapper
    over_numpy = rates["torchrl_env", large] / rates["numpy_engine", large]
    torch_over_numpy = rates["torch_engine", large] / rates["numpy_engine", large]
    lines += [
        "",
        f"ConsensusTorchEnv (B×N = {small:,}) / PettingZoo wrapper (N = 6), agent-steps/s: {over_wrapper:,.0f}x "
        f"(goal >= {TORCHRL_WRAPPER_GOAL:,.0f}x: {met(over_wrapper >= TORCHRL_WRAPPER_GOAL)})",
        f"ConsensusTorchEnv / numpy engine at {large:,} agents: {over_numpy:.0%} "
        f"(goal >= {TORCHRL_NUMPY_GOAL:.0%}: {met(over_numpy >= TORCHRL_NUMPY_GOAL)})",
        f"torch engine (CPU) / numpy engine at {large:,} agents: {torch_over_numpy:.0%}",
    ]
    return lines
