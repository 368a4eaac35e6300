"""``fxc evaluate``: a learned policy next to the reference on the deadline benchmark.

The suite is the paper's example plus the generalisation graphs of issue 5 (directed
``ring``, ``path`` and ``random`` at N = 20), 20 seeded initial states each, at the
reference's budget K = 200; the table, CSVs and plots are the benchmark's
(:mod:`fxc_env.baselines.benchmark`), written to ``out/evaluate`` by default.
"""

from __future__ import annotations

import argparse
import sys

from fxc_env.baselines.benchmark import run_benchmark
from fxc_env.baselines.suite import Scenario, Suite, builtin_contenders, learned_contender
from fxc_env.core.validation import ArgumentError

EVALUATION_SCENARIOS = (
    Scenario("paper_fig1", 6),
    Scenario("ring", 20),
    Scenario("path", 20),
    Scenario("random", 20),
)


def evaluation_suite(n_seeds: int = 20, budgets: tuple[int, ...] = (200,)) -> Suite:
    """``paper_fig1`` and the N = 20 generalisation graphs, seeds ``0 .. n_seeds - 1``."""
    return Suite(
        scenarios=EVALUATION_SCENARIOS,
        seeds=tuple(range(n_seeds)),
        budgets=budgets,
        fine_intervals=1000,
        headline_budget=max(budgets) if 200 not in budgets else 200,
        name="evaluate",
    )


def add_evaluate_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``fxc evaluate``."""
    parser = commands.add_parser(
        "evaluate",
        help="score a learned policy next to the reference (paper_fig1 and N=20 ring, path, random)",
    )
    parser.add_argument(
        "--policy",
        required=True,
        help="'reference', 'pretrained' (shipped with fxc_env), the path of a saved SB3 model (.zip), "
        "or an RLlib checkpoint or run directory (fxc train --backend rllib)",
    )
    parser.add_argument("--seeds", type=int, default=20, help="seeded initial states per scenario")
    parser.add_argument("--budgets", default="200", help="comma-separated K values (default 200)")
    parser.add_argument("--out", default="out/evaluate", help="directory for table.md, CSVs and PNGs")
    parser.add_argument("--workers", type=int, help="processes (default: one per core)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=evaluate_command)


def evaluate_command(args: argparse.Namespace) -> int:
    if args.seeds < 1:
        raise ArgumentError(f"--seeds: expected an integer >= 1, got {args.seeds}")
    try:
        budgets = tuple(int(k) for k in args.budgets.split(","))
    except ValueError as exc:
        raise ArgumentError(f"--budgets: expected comma-separated integers, got {args.budgets!r}") from exc
    contenders = builtin_contenders(["reference"])
    if args.policy != "reference":
        contenders.append(learned_contender(args.policy))
    command = "fxc " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["evaluate"] else None
    output = run_benchmark(
        evaluation_suite(args.seeds, budgets),
        contenders,
        args.out,
        workers=args.workers,
        progress=not args.no_progress,
        command=command,
    )
    print(output.markdown)
    print("wrote " + ", ".join(str(f) for f in output.files))
    return 0
