"""``fxc speed``'s command (``python -m fxc_env.speed`` too): its options, which tables of :mod:`fxc_env.speed`
run, in order, and the closing report of every goal line of the run.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

from fxc_env.config.argument_types import FlagParser
from fxc_env.core.validation import MAX_AGENTS, ArgumentError, integer
from fxc_env.speed.scaling import SCALING_FIRST_N
from fxc_env.speed.timing import importable, machine_description
from fxc_env.utils.threads import THREAD_VARIABLES, pin_threads_or_reexec

#: What ``python -m`` runs (the module re-executed with one thread per library).
MODULE = "fxc_env.speed"
BENCH_HINT = 'install the optional extra: .venv/bin/pip install -c constraints.txt -e ".[bench]"'
#: The CPU tables, in the order they print (the default selection).
CPU_TABLES = ("parallel", "vecenv", "torchrl", "training", "scaling", "models")
#: Every table ``--only`` may name.
TABLES = (*CPU_TABLES, "cuda")
#: Tables that use other libraries: the contenders' comparisons, and the training table (SB3,
#: TorchRL; it trains whole PPO rollouts). ``--skip-contenders`` leaves them out.
COMPARISONS = ("parallel", "vecenv", "torchrl", "training")
#: Modules each table needs, and the optional extra that brings each module.
TABLE_MODULES = {"parallel": ("mpe2",), "vecenv": ("vmas",), "torchrl": ("torchrl", "tensordict")}
MODULE_EXTRAS = {"mpe2": "bench", "vmas": "bench", "torchrl": "torchrl", "tensordict": "torchrl"}


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``fxc speed``'s options on ``parser`` (the ``fxc`` command's subparser, or :func:`main`'s own)."""
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds per contender")
    parser.add_argument("--total-agents", type=int, default=100_000, help="agents in all for the VecEnv vs VMAS table")
    parser.add_argument("--largest", type=int, default=1_000_000, help="largest N of the scaling table")
    parser.add_argument(
        "--skip-contenders",
        action="store_true",
        help="no other libraries: the scaling and agent-model tables only (no MPE2, VMAS, TorchRL, "
        "and no training), or the CUDA table without VMAS and JaxMARL",
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
    return [module for module in dict.fromkeys(needed) if not importable(module)]


def install_hint(modules: Sequence[str]) -> str:
    """The pip command that brings ``modules`` (their optional extras)."""
    extras = ",".join(dict.fromkeys(MODULE_EXTRAS.get(module, "bench") for module in modules))
    if extras == "bench":
        return BENCH_HINT
    return f'install the optional extras: .venv/bin/pip install -c constraints.txt -e ".[{extras}]"'


def run(args: Any) -> int:
    """Print the selected tables (``args``: ``rounds``, ``total_agents``, ``largest``, ``skip_contenders``,
    and optionally ``device`` and ``only``, see :func:`add_arguments`), then every goal line of the run."""
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
    goals: list[str] = []

    def out(text: str) -> None:
        goals.extend(line for line in text.splitlines() if "(goal" in line)
        print(text, flush=True)

    for table in tables:
        if table == "cuda":
            from fxc_env.speed.cuda import cuda_tables

            cuda_tables(device, args.rounds, contenders=not args.skip_contenders, out=out)
            continue
        title, lines = TABLE_RUNNERS[table](args)
        out(f"\n## {title}\n")
        out("\n".join(lines))
    if goals:
        out("\n## Goals measured in this run\n")
        out("\n".join(f"- {line}" for line in goals))
    return 0


def _parallel(args: Any) -> tuple[str, list[str]]:
    from fxc_env.speed.parallel import parallel_table

    return "ParallelEnv vs MPE2 (dict API, random actions, resets included)", parallel_table(args.rounds)


def _vecenv(args: Any) -> tuple[str, list[str]]:
    from fxc_env.speed.vecenv import vec_table

    title = f"ConsensusVecEnv vs VMAS on CPU (>= {args.total_agents:,} agents, one thread)"
    return title, vec_table(args.total_agents, args.rounds)


def _torchrl(args: Any) -> tuple[str, list[str]]:
    from fxc_env.speed.torchrl import torchrl_table

    title = (
        "TorchRL on CPU: the PettingZoo wrapper, ConsensusTorchEnv and the engine (paper_fig1, N = 6, "
        "reference policy, resets included, one thread)"
    )
    return title, torchrl_table(args.rounds)


def _training(args: Any) -> tuple[str, list[str]]:
    from fxc_env.speed.training import training_table

    title = f"Training: PPO end to end on paper_fig1, {os.cpu_count()} torch threads (set-up, collection, updates)"
    return title, training_table()


def _scaling(args: Any) -> tuple[str, list[str]]:
    from fxc_env.speed.scaling import SCALING_DIMS, scaling_table

    title = "One episode on random digraphs (mean in-degree 4), reference policy, dim = 1, 2, 3"
    return title, scaling_table(args.largest, SCALING_DIMS)


def _models(args: Any) -> tuple[str, list[str]]:
    from fxc_env.speed.models import MODELS_N, models_table

    title = f"Agent models: one episode of N = {MODELS_N:,} on a random digraph (mean in-degree 4), reference, dim = 1"
    return title, models_table()


#: Each CPU table's title and lines from the parsed options.
TABLE_RUNNERS: dict[str, Callable[[Any], tuple[str, list[str]]]] = {
    "parallel": _parallel,
    "vecenv": _vecenv,
    "torchrl": _torchrl,
    "training": _training,
    "scaling": _scaling,
    "models": _models,
}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m fxc_env.speed [options]``: ``fxc speed`` without the rest of the ``fxc`` command.

    For machines that have the package but not every dependency of the ``fxc`` command (a
    GPU box with ``pip install --no-deps -e .``). Usage errors print as one line (exit 2).
    """
    import fxc_env.speed

    description = fxc_env.speed.__doc__.splitlines()[0]  # the package's: what fxc speed measures
    parser = add_arguments(FlagParser(prog="fxc speed", description=description))
    arguments = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(arguments)
    try:
        check_arguments(args)
        pin_threads_or_reexec(MODULE, arguments)
        return run(args)
    except ArgumentError as exc:
        message = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        print(f"fxc speed: error: {message}", file=sys.stderr)
        return 2
