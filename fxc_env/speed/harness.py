"""``fxc speed``: throughput measured side by side with the environments users would otherwise pick.

The CPU tables (the default), all from one run on one machine, contenders alternated round
by round so that both see the same machine state; each figure is the median over rounds:

1. ``parallel``: our PettingZoo ParallelEnv against MPE2 ``simple_spread_v3`` (continuous
   actions) at N = 6 and N = 20, in env-steps per second through the dict API, random actions;
2. ``vecenv``: our SB3 ``ConsensusVecEnv`` driven by the reference policy against VMAS on the
   CPU (``navigation`` and ``simple_spread``, random actions) at the same total agent count
   (>= 1e5), in agent-steps per second;
3. ``torchrl``: at N = 6 (``paper_fig1``), agent-steps per second of the environment in
   TorchRL's ``PettingZooWrapper`` (:func:`fxc_env.envs.interop.torchrl_wrapper`, one episode), of the
   native batched :class:`fxc_env.envs.torch_env.ConsensusTorchEnv` (``env.step`` + ``step_mdp``,
   ``reference_policy(env)``) at B x N of about 6e3 and 1e5 agents, and of the batched engine
   alone (observations -> :class:`~fxc_env.policies.reference.ReferencePolicy` -> step) on torch and on
   numpy at the same sizes; the goals: ``ConsensusTorchEnv`` >= 1000x the wrapper at 6e3
   agents, and >= 50% of the numpy engine at 1e5 agents;
4. ``scaling``: one episode on ``random`` digraphs (mean in-degree 4) from N = 10^2 to 10^6,
   for ``dim`` = 1, 2 and 3: seconds per sampling interval (observation + reference policy +
   exact step), per agent-step, and the peak memory traced while building and stepping;
   then the time per interval at ``dim`` = 2 and 3 over that at ``dim`` = 1, at N = 10^5
   (the goal: ``dim`` = 2 within 3x).

``--device cuda`` runs the ``cuda`` table instead: the engine and the reference on torch CUDA
(float64, ``dim`` = 1) from 1e4 to 1e8 agents (N = 1000 random digraphs and N = 6
``paper_fig1``, B episodes each; a size that does not fit in the GPU's memory is skipped with
a note), single episodes of N = 1e6 and 1e7 (ms per interval), and, where importable, VMAS
``simple_spread`` (torch CUDA) and JaxMARL ``MPE_simple_spread_v3`` (``jit`` + ``vmap``) at
262,144 environments, alternated with the engine round by round. ``--only`` picks tables by
name (``--only torchrl``, ``--only cuda``, ``--only parallel,scaling``).

Threads are pinned to one (``OMP_NUM_THREADS`` and friends are set before numpy or torch
start, by re-running the command; ``torch.set_num_threads(1)``). MPE2 and VMAS come from
the optional extra ``bench``, TorchRL from ``torchrl``:
``.venv/bin/pip install -c constraints.txt -e ".[bench,torchrl]"``. Without the ``fxc``
command (a bare GPU machine), ``python -m fxc_env.speed.harness --device cuda`` runs the same code.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import statistics
import sys
import time
import tracemalloc
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fxc_env.core.validation import MAX_AGENTS, ArgumentError, integer
from fxc_env.utils.threads import THREAD_VARIABLES, pin_threads_or_reexec

BENCH_HINT = 'install the optional extra: .venv/bin/pip install -c constraints.txt -e ".[bench]"'
#: The CPU tables, in the order they print (the default selection).
CPU_TABLES = ("parallel", "vecenv", "torchrl", "training", "scaling", "models")
#: Every table ``--only`` may name.
TABLES = (*CPU_TABLES, "cuda")
#: Tables that compare with other libraries (left out by ``--skip-contenders``).
COMPARISONS = ("parallel", "vecenv", "torchrl")
#: Modules each table needs, and the optional extra that brings each module.
TABLE_MODULES = {"parallel": ("mpe2",), "vecenv": ("vmas",), "torchrl": ("torchrl", "tensordict")}
MODULE_EXTRAS = {"mpe2": "bench", "vmas": "bench", "torchrl": "torchrl", "tensordict": "torchrl"}
#: The first N of the scaling table; ``--largest`` is at least this.
SCALING_FIRST_N = 100


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


def timed_rate(step: Callable[[], None], count: int, sync: Callable[[], None] | None = None) -> float:
    """Calls of ``step`` per second over ``count`` calls (``sync``, e.g. ``torch.cuda.synchronize``, on both ends)."""
    if sync is not None:
        sync()
    start = time.perf_counter()
    for _ in range(count):
        step()
    if sync is not None:
        sync()
    return count / (time.perf_counter() - start)


def calibrated_count(
    step: Callable[[], None], seconds: float, sync: Callable[[], None] | None = None, most: int = 2000
) -> int:
    """How many calls of ``step`` take about ``seconds`` (at least 3): one warm-up call, then 3 timed."""
    step()
    return int(min(most, max(3, timed_rate(step, 3, sync) * seconds)))


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


# ----------------------------------------------------------------- scaling table
#: The scaling table's dimensions: the paper's ``dim = 1``, then the plane and space.
SCALING_DIMS = (1, 2, 3)
#: N at which the table compares each ``dim`` with ``dim = 1``, and the goal for ``dim = 2``.
RATIO_N = 100_000
RATIO_GOAL = 3.0


def scaling_row(n_agents: int, steps: int, dim: int = 1, **model: Any) -> tuple[float, float, float]:
    """(seconds per interval, seconds per agent-step, peak traced MiB) for one episode in ``dim`` dimensions.

    ``model``: ``agent_model`` and its parameters (default: the double integrator's closed forms).
    """
    from fxc_env.config import make_config
    from fxc_env.engine import ConsensusEngine
    from fxc_env.policies.reference import ReferencePolicy

    tracemalloc.start()
    config = make_config(
        topology="random", n_agents=n_agents, mean_in_degree=4.0, n_intervals=steps + 1, dim=dim, **model
    )
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
    return lines


#: Agents of the agent-model table, and its goal: the general path within 10x the closed forms per agent-step.
MODELS_N = 100_000
MODELS_GOAL = 10.0


def models_table(n_agents: int = MODELS_N, steps: int = 20) -> list[str]:
    """Time per agent-step of every agent model in one episode of ``n_agents`` (random digraph, dim = 1).

    The double integrator twice: by its closed forms, and as ``(A, B)`` through the general
    path (matrix exponentials and the scaled Gramian, :mod:`fxc_env.core.linear`), whose ratio
    is the goal line.
    """
    from fxc_env.core.linear import model_matrices

    models = [
        ("double_integrator (closed forms)", {}),
        ("double_integrator as (A, B) (general path)", {"agent_model": model_matrices("double_integrator")}),
        ("single_integrator", {"agent_model": "single_integrator"}),
        ("integrator_chain, order 3", {"agent_model": "integrator_chain", "order": 3}),
        ("integrator_chain, order 4", {"agent_model": "integrator_chain", "order": 4}),
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
        f"general path / closed forms at N={n_agents:,}: {general:.1f}x (goal <= {MODELS_GOAL:g}x: {_met(general <= MODELS_GOAL)})",
    ]
    return lines


#: Agent-steps each back end trains for in the training table (whole PPO rollouts on paper_fig1).
TRAINING_TIMESTEPS = {"sb3": 2 * 16 * 6 * 200, "torchrl": 8 * 64 * 6 * 200}
#: The torch back end's goal: agent-steps per second of PPO (collection and updates) on the CPU.
TRAINING_GOAL = 1e5


def training_rate(backend: str, timesteps: int, threads: int) -> tuple[float, float]:
    """(agent-steps/s over the run, wall seconds) of ``fxc train --backend`` on paper_fig1, PPO, in a scratch directory."""
    import contextlib
    import io
    import tempfile

    from fxc_env.training.args import TrainArgs
    from fxc_env.training.backends import train

    with tempfile.TemporaryDirectory() as scratch, contextlib.redirect_stdout(io.StringIO()):
        start = time.perf_counter()
        args = TrainArgs(
            scenario="paper_fig1",
            backend=backend,
            timesteps=timesteps,
            run_dir=scratch,
            progress_bar=False,
            torch_threads=threads,
            checkpoint_every=10**9,
        )
        train(args)
        seconds = time.perf_counter() - start
    return timesteps / seconds, seconds


def torchrl_collector_rate(rollouts: int = 3, episodes: int = 64, epochs: int = 2, minibatch: int = 2048) -> float:
    """Agent-steps/s of PPO written with TorchRL's own pieces on :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv`.

    ``Collector`` + ``ClipPPOLoss`` (GAE, a replay buffer of one rollout, TanhNormal actor)
    with the torch back end's settings on paper_fig1 (B = ``episodes``, one whole episode a
    rollout, ``epochs`` passes in minibatches of ``minibatch`` agent-steps, 64 x 64 tanh
    networks): the alternative ``--backend torchrl`` was measured against. The first
    rollout (warm-up) is not timed.
    """
    import torch
    from tensordict.nn import TensorDictModule
    from torch import nn
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, ReplayBuffer
    from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement
    from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    from fxc_env.envs.torch_env import GROUP, ConsensusTorchEnv

    env = ConsensusTorchEnv(
        batch_size=episodes, seed=0, obs_dtype="float32", scenario="paper_fig1", obs_slots=4, initial_state="random"
    )
    size, actions, bound = env.config.layout.size, env.config.action_size, env.config.action_bound
    steps = env.config.n_intervals

    def mlp(inputs: int, outputs: int) -> nn.Module:
        return nn.Sequential(nn.Linear(inputs, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, outputs))

    class Gaussian(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mean = mlp(size, actions)
            self.log_std = nn.Parameter(torch.full((actions,), -2.0))

        def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            loc = self.mean(observation)
            return loc, torch.exp(self.log_std).expand_as(loc)

    keys = [(GROUP, "loc"), (GROUP, "scale")]
    actor = ProbabilisticActor(
        TensorDictModule(Gaussian(), in_keys=[(GROUP, "observation")], out_keys=keys),
        in_keys=keys,
        out_keys=[(GROUP, "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -bound, "high": bound},
        return_log_prob=True,
        log_prob_key=(GROUP, "sample_log_prob"),
    )
    critic = ValueOperator(mlp(size, 1), in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "state_value")])
    frames = episodes * steps
    collector = Collector(
        env,
        actor,
        frames_per_batch=frames,
        total_frames=frames * (rollouts + 1),
        device="cpu",
        auto_register_policy_transforms=False,
    )
    loss = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=0.2, entropy_coeff=0.0)
    loss.set_keys(
        reward=(GROUP, "reward"),
        action=(GROUP, "action"),
        sample_log_prob=(GROUP, "sample_log_prob"),
        value=(GROUP, "state_value"),
        done=(GROUP, "done"),
        terminated=(GROUP, "terminated"),
    )
    loss.make_value_estimator(ValueEstimators.GAE, gamma=1.0, lmbda=0.95)
    optimiser = torch.optim.Adam(loss.parameters(), lr=3e-4, eps=1e-5)
    per_minibatch = max(1, minibatch // env.n_agents)
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(frames), sampler=SamplerWithoutReplacement(), batch_size=per_minibatch
    )
    seconds, start = 0.0, time.perf_counter()
    for index, data in enumerate(collector):
        for key in ("done", "terminated"):  # the group's per-agent flags, from the episode's
            shape = data.get_item_shape(("next", GROUP, "reward"))
            data.set(("next", GROUP, key), data.get(("next", key)).unsqueeze(-1).expand(shape))
        with torch.no_grad():
            loss.value_estimator(
                data, params=loss.critic_network_params, target_params=loss.target_critic_network_params
            )
        buffer.extend(data.reshape(-1))
        for _ in range(epochs * (frames // per_minibatch)):
            values = loss(buffer.sample())
            total = values["loss_objective"] + values["loss_critic"] + values["loss_entropy"]
            optimiser.zero_grad()
            total.backward()
            nn.utils.clip_grad_norm_(loss.parameters(), 0.5)
            optimiser.step()
        collector.update_policy_weights_()
        if index:
            seconds += time.perf_counter() - start
        start = time.perf_counter()
    collector.shutdown()
    return rollouts * frames * env.n_agents / seconds


def training_table(threads: int | None = None) -> list[str]:
    """PPO's throughput, end to end (collection, updates, logging; set-up included), per back end on paper_fig1.

    SB3 on :class:`~fxc_env.envs.vec_env.ConsensusVecEnv` and the torch back end on the torch
    engine, each with ``threads`` torch threads (default: every core); RLlib needs Ray, which
    lives in ``.venv-rllib`` (``fxc train --backend rllib`` prints its own rate there).
    """
    import torch

    threads = threads or os.cpu_count() or 1
    previous = torch.get_num_threads()
    lines = ["| back end | agent-steps | wall (s) | agent-steps/s | vs SB3 |", "|---|---:|---:|---:|---:|"]
    rates = {}
    try:
        for backend, timesteps in TRAINING_TIMESTEPS.items():
            rates[backend], seconds = training_rate(backend, timesteps, threads)
            lines.append(
                f"| {backend} | {timesteps:,} | {seconds:.1f} | {rates[backend]:,.0f} | {rates[backend] / rates['sb3']:.1f}x |"
            )
    finally:
        torch.set_num_threads(previous)
    if _importable("torchrl"):
        torch.set_num_threads(threads)
        rate = torchrl_collector_rate()
        torch.set_num_threads(previous)
        lines.append(
            f"| TorchRL Collector + ClipPPOLoss on ConsensusTorchEnv (same settings, not shipped) | 3 rollouts | | "
            f"{rate:,.0f} | {rate / rates['sb3']:.1f}x |"
        )
    if _importable("ray"):
        lines.append("| rllib | | | (run `fxc train --backend rllib`: it prints its rate) | |")
    else:
        lines.append("| rllib | | | not in this environment (Ray lives in .venv-rllib) | |")
    rate = rates["torchrl"]
    lines += [
        "",
        f"torch back end: {rate:,.0f} agent-steps/s with {threads} threads "
        f"(goal >= {TRAINING_GOAL:,.0f}: {_met(rate >= TRAINING_GOAL)})",
    ]
    return lines


# ------------------------------------------------------------------ TorchRL
#: B x N of the TorchRL table's two batch sizes (about; B is rounded up to whole episodes of 6).
TORCHRL_SIZES = (6_000, 100_000)
#: The TorchRL table's goals: ConsensusTorchEnv over the PettingZoo wrapper at the small size,
#: and over the numpy engine at the large one.
TORCHRL_WRAPPER_GOAL = 1000.0
TORCHRL_NUMPY_GOAL = 0.5
#: Seconds of one timed block (the number of steps is calibrated per contender).
BLOCK_SECONDS = 0.25


def engine_stepper(config: Any, n_episodes: int, device: Any = None, seed: int = 0) -> tuple[Callable[[], None], Any]:
    """One interval of B episodes: ``engine.observations`` -> ``ReferencePolicy.act`` -> ``engine.step``.

    ``device`` None is numpy (observations written into one buffer, as the VecEnv does),
    else a torch device. Episodes restart together (``draw_batch`` + ``reset``) at ``T_s``.
    Returns the step and the engine (for :meth:`~fxc_env.engine.ConsensusEngine.raise_if_invalid`).
    """
    from fxc_env.engine import ConsensusEngine
    from fxc_env.policies.reference import ReferencePolicy

    engine = ConsensusEngine(config, n_episodes, device=device)
    engine.seed(seed)
    policy = ReferencePolicy(config)
    host_rng = np.random.default_rng(seed)

    def restart() -> None:
        x0, v0, u_max, topologies = engine.draw_batch(host_rng)
        engine.reset(x0, v0, topologies=topologies, u_max=u_max)

    restart()
    buffer = np.empty((n_episodes, config.n_agents, config.layout.size)) if engine.is_numpy else None

    def step() -> None:
        engine.step(policy.act(engine.observations(buffer)))
        if engine.done:
            restart()

    return step, engine


def torchrl_wrapper_stepper(seed: int = 0) -> Callable[[], None]:
    """One env-step of ``paper_fig1`` in TorchRL's ``PettingZooWrapper`` (:func:`fxc_env.envs.interop.torchrl_wrapper`).

    The reference policy as a ``TensorDictModule`` on the group's observations, then
    ``env.step`` and ``step_mdp``; ``env.reset()`` when the episode is done.
    """
    from tensordict.nn import TensorDictModule
    from torchrl.envs.utils import step_mdp

    from fxc_env.config import make_config
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
    state = {"td": env.reset()}

    def step() -> None:
        td = step_mdp(env.step(policy(state["td"])))
        state["td"] = env.reset() if bool(td["done"].any()) else td

    return step


def torchrl_batched_stepper(n_episodes: int, seed: int = 0, device: str = "cpu") -> Callable[[], None]:
    """One step of :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv` (``paper_fig1``, B episodes).

    What a TorchRL user writes: ``reference_policy(env)``, ``env.step``, ``step_mdp``, and
    ``env.reset()`` once the episodes are done.
    """
    from torchrl.envs.utils import step_mdp

    from fxc_env.envs.torch_env import ConsensusTorchEnv
    from fxc_env.policies.torchrl_reference import reference_policy

    env = ConsensusTorchEnv(batch_size=n_episodes, device=device, seed=seed, scenario="paper_fig1")
    policy = reference_policy(env)
    state = {"td": env.reset()}

    def step() -> None:
        td = step_mdp(env.step(policy(state["td"])))
        state["td"] = env.reset() if bool(td["done"].any()) else td

    return step


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
    from fxc_env.config import make_config

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


def _met(met: bool) -> str:
    return "met" if met else "not met"


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
        f"(goal >= {TORCHRL_WRAPPER_GOAL:,.0f}x: {_met(over_wrapper >= TORCHRL_WRAPPER_GOAL)})",
        f"ConsensusTorchEnv / numpy engine at {large:,} agents: {over_numpy:.0%} "
        f"(goal >= {TORCHRL_NUMPY_GOAL:.0%}: {_met(over_numpy >= TORCHRL_NUMPY_GOAL)})",
        f"torch engine (CPU) / numpy engine at {large:,} agents: {torch_over_numpy:.0%}",
    ]
    return lines


# ------------------------------------------------------------------ CUDA
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

    if torch.device(device).type != "cuda":
        return None
    return lambda: torch.cuda.synchronize(device)


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
    from fxc_env.config import make_config

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
    from fxc_env.config import make_config

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
        if _importable("vmas"):
            try:
                step = vmas_stepper("simple_spread", agents, device=str(device))[0]
                add(f"VMAS simple_spread (torch on {device}, float32, random actions)", step, 1, synchronizer(device))
            except Exception as error:  # an optional contender that fails to start is reported, not fatal
                notes.append(f"VMAS simple_spread: skipped ({type(error).__name__}: {error})".splitlines()[0])
        else:
            notes.append("VMAS: not importable here (pip install vmas)")
        if _importable("jaxmarl") and _importable("jax"):
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
            f"(N = {n:,}, {agents:,} agents) (goal >= {CUDA_RATE_GOAL:,.0f}: {_met(best >= CUDA_RATE_GOAL)})"
        )
    else:
        out(
            f"\nno size of >= {CUDA_RATE_AT:,} agents was measured (goal >= {CUDA_RATE_GOAL:,.0f} agent-steps/s: not met)"
        )
    out(f"\n## One episode on a random digraph (mean in-degree 4), engine + reference on {device}\n")
    lines, intervals = cuda_single_table(device, rounds, single, seconds)
    out("\n".join(lines))
    goals = [
        f"N={n:,}: {intervals[n]:.3f} ms (goal <= {CUDA_SINGLE[n]:g} ms: {_met(intervals[n] <= CUDA_SINGLE[n])})"
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


# ------------------------------------------------------------------ arguments and report
def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``fxc speed``'s options on ``parser`` (the ``fxc`` command's subparser, or :func:`main`'s own)."""
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds per contender")
    parser.add_argument("--total-agents", type=int, default=100_000, help="agents in all for the VecEnv vs VMAS table")
    parser.add_argument("--largest", type=int, default=1_000_000, help="largest N of the scaling table")
    parser.add_argument(
        "--skip-contenders",
        action="store_true",
        help="no comparison with other libraries: the scaling table only (no MPE2/VMAS/TorchRL), "
        "or the CUDA table without VMAS and JaxMARL",
    )
    add_selection_arguments(parser)
    return parser


def add_selection_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``--device`` and ``--only``: which tables run, and where the CUDA table runs."""
    parser.add_argument(
        "--device",
        default="cpu",
        help="cpu (default): the CPU tables; cuda (or cuda:<index>): the CUDA table (engine + reference on the GPU)",
    )
    parser.add_argument(
        "--only",
        default=None,
        help=f"comma-separated tables to run, of: {', '.join(TABLES)} (default: the CPU tables, or cuda with --device cuda)",
    )
    return parser


def _is_cuda(device: str) -> bool:
    return device == "cuda" or (device.startswith("cuda:") and device[5:].isdigit())


def selected_tables(args: Any) -> tuple[tuple[str, ...], str]:
    """The tables to run and the CUDA device, from ``args``; :class:`ArgumentError` naming the option otherwise.

    ``args`` without ``device`` or ``only`` (an older parser) runs the CPU tables.
    """
    device = getattr(args, "device", None) or "cpu"
    only = getattr(args, "only", None)
    if not isinstance(device, str) or not (device == "cpu" or _is_cuda(device)):
        raise ArgumentError(f"--device: expected cpu, cuda or cuda:<index>, got {device!r}")
    if only is None:
        tables = ("cuda",) if _is_cuda(device) else CPU_TABLES
    else:
        names = [name.strip() for name in str(only).split(",")]
        unknown = [name for name in names if name not in TABLES]
        if unknown:
            raise ArgumentError(
                f"--only: expected table names separated by commas, of {', '.join(TABLES)}; got {only!r}"
                + f" (unknown: {', '.join(repr(name) for name in unknown)})"
            )
        tables = tuple(name for name in TABLES if name in names)
    if getattr(args, "skip_contenders", False):
        kept = tuple(name for name in tables if name not in COMPARISONS)
        if not kept:
            raise ArgumentError(
                f"--only: {', '.join(tables)} compare with other libraries, which --skip-contenders leaves out"
            )
        tables = kept
    if "cuda" in tables or _is_cuda(device):
        device = device if _is_cuda(device) else "cuda"
        import torch

        if not torch.cuda.is_available():
            raise ArgumentError(
                f"--device: {device!r} needs CUDA, but torch.cuda.is_available() is False on this machine "
                f"(torch {torch.__version__}); leave out --device (and --only cuda) for the CPU tables"
            )
        index = torch.device(device).index
        if index is not None and index >= torch.cuda.device_count():
            raise ArgumentError(
                f"--device: {device!r}, but this machine has {torch.cuda.device_count()} CUDA device(s)"
            )
    return tables, device


def check_arguments(args: Any) -> tuple[tuple[str, ...], str]:
    """Every option of ``fxc speed`` checked (usage errors name the option): the tables and the CUDA device."""
    integer("--rounds", args.rounds, 1)
    integer("--total-agents", args.total_agents, 1, MAX_AGENTS)
    integer("--largest", args.largest, SCALING_FIRST_N, MAX_AGENTS)
    return selected_tables(args)


def missing_modules(tables: Sequence[str]) -> list[str]:
    """Modules the selected tables need that are not importable here."""
    needed = [module for table in tables for module in TABLE_MODULES.get(table, ())]
    return [module for module in dict.fromkeys(needed) if not _importable(module)]


def install_hint(modules: Sequence[str]) -> str:
    """The pip command that brings ``modules`` (their optional extras)."""
    extras = ",".join(dict.fromkeys(MODULE_EXTRAS.get(module, "bench") for module in modules))
    if extras == "bench":
        return BENCH_HINT
    return f'install the optional extras: .venv/bin/pip install -c constraints.txt -e ".[{extras}]"'


def run(args: Any) -> int:
    """Print the selected tables (``args``: ``rounds``, ``total_agents``, ``largest``, ``skip_contenders``,
    and optionally ``device`` and ``only``, see :func:`add_arguments`)."""
    tables, device = check_arguments(args)
    import torch

    torch.set_num_threads(1)
    print("# fxc speed")
    print(f"machine: {machine_description()}")
    print("threads: " + ", ".join(f"{name}={os.environ.get(name)}" for name in THREAD_VARIABLES) + ", torch 1")
    print(f"rounds per contender: {args.rounds} (alternating; median reported)")
    print(f"tables: {', '.join(tables)}")
    missing = missing_modules(tables)
    if missing:
        print(
            f"fxc speed: {', '.join(missing)} missing; {install_hint(missing)} (or pass --skip-contenders)",
            file=sys.stderr,
        )
        return 2
    if "parallel" in tables:
        _section("ParallelEnv vs MPE2 (dict API, random actions, resets included)", parallel_table(args.rounds))
    if "vecenv" in tables:
        _section(
            f"ConsensusVecEnv vs VMAS on CPU (>= {args.total_agents:,} agents, one thread)",
            vec_table(args.total_agents, args.rounds),
        )
    if "torchrl" in tables:
        _section(
            "TorchRL on CPU: the PettingZoo wrapper, ConsensusTorchEnv and the engine (paper_fig1, N = 6, "
            "reference policy, resets included, one thread)",
            torchrl_table(args.rounds),
        )
    if "training" in tables:
        _section(
            f"Training: PPO end to end on paper_fig1, {os.cpu_count()} torch threads (set-up, collection, updates)",
            training_table(),
        )
    if "scaling" in tables:
        _section(
            "One episode on random digraphs (mean in-degree 4), reference policy, dim = 1, 2, 3",
            scaling_table(args.largest, SCALING_DIMS),
        )
    if "models" in tables:
        _section(
            f"Agent models: one episode of N = {MODELS_N:,} on a random digraph (mean in-degree 4), reference, dim = 1",
            models_table(),
        )
    if "cuda" in tables:
        cuda_tables(device, args.rounds, contenders=not args.skip_contenders, out=lambda text: print(text, flush=True))
    return 0


def _section(title: str, lines: list[str]) -> None:
    print(f"\n## {title}\n")
    print("\n".join(lines), flush=True)


def _importable(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m fxc_env.speed.harness [options]``: ``fxc speed`` without the rest of the ``fxc`` command.

    For machines that have the package but not every dependency of the ``fxc`` command (a
    GPU box with ``pip install --no-deps -e .``). Usage errors print as one line (exit 2).
    """
    parser = add_arguments(argparse.ArgumentParser(prog="fxc speed", description=__doc__.splitlines()[0]))
    arguments = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(arguments)
    try:
        check_arguments(args)
        pin_threads_or_reexec("fxc_env.speed.harness", arguments)
        return run(args)
    except ArgumentError as exc:
        message = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        print(f"fxc speed: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
