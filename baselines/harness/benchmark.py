"""``fxc benchmark``: every policy on the same cases, scored at the deadline ``T_s``.

Each job (:mod:`fxc_env.baselines.harness.jobs`) runs all seeded initial states of the suite as one batch on a
:class:`ConsensusEngine`; jobs are spread over the machine's cores (one BLAS thread each) or, with ``--ray``,
over a Ray cluster (:mod:`fxc_env.baselines.harness.ray_jobs`); :mod:`fxc_env.baselines.harness.report` and
:mod:`fxc_env.baselines.harness.figures` are built from the results. ``--quick`` runs a smaller suite.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fxc_env.baselines.harness import dropout, figures, report
from fxc_env.baselines.harness.jobs import JobResult, make_jobs, run_in_processes
from fxc_env.baselines.harness.resolution import with_resolution
from fxc_env.baselines.harness.suite import (
    Contender,
    Suite,
    builtin_contenders,
    full_suite,
    learned_contender,
    models_suite,
    optimality_contenders,
    optimality_suite,
    quick_optimality_suite,
    quick_suite,
    realism_suite,
)
from fxc_env.baselines.registry import LAWS
from fxc_env.core.validation import MAX_INTERVALS, ArgumentError, integer
from fxc_env.utils.cli_checks import output_directory


def run_suite(
    suite: Suite,
    contenders: list[Contender],
    *,
    workers: int | None = None,
    progress: bool = True,
    ray: bool = False,
    address: str | None = None,
) -> list[JobResult]:
    """Run every job of the suite; results in table order.

    Over ``workers`` processes (default: all cores), or with ``ray`` as Ray tasks on a local Ray or on the
    cluster at ``address``; both give the same results.
    """
    from tqdm import tqdm

    jobs = make_jobs(suite, contenders)
    order = {job: i for i, job in enumerate(jobs)}
    longest_first = sorted(jobs, key=lambda j: -j.cost)
    bar = tqdm(total=len(jobs), desc=f"fxc benchmark ({suite.name})", unit="job", disable=not progress)
    with bar:
        if ray:
            from fxc_env.baselines.harness.ray_jobs import run_jobs_on_ray

            results = run_jobs_on_ray(longest_first, address=address, num_cpus=workers, on_done=bar.update)
            for result, job in zip(results, longest_first, strict=True):
                result.job = job
        else:
            results = run_in_processes(longest_first, workers, on_done=bar.update)
    return sorted(results, key=lambda r: order[r.job])


@dataclass(frozen=True)
class BenchmarkOutput:
    """The report and the files a benchmark run wrote."""

    markdown: str
    files: list[Path]
    results: list[JobResult]
    seconds: float


def run_benchmark(
    suite: Suite,
    contenders: list[Contender],
    out_dir: Path | str = "out/benchmark",
    *,
    workers: int | None = None,
    progress: bool = True,
    command: str | None = None,
    ray: bool = False,
    address: str | None = None,
) -> BenchmarkOutput:
    """Run the suite (see :func:`run_suite`), then write ``table.md``, ``results.csv``, ``episodes.csv`` and three PNGs."""
    start = time.perf_counter()
    results = run_suite(suite, contenders, workers=workers, progress=progress, ray=ray, address=address)
    seconds = time.perf_counter() - start
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = report.aggregate(results)
    markdown = report.markdown_report(results, suite, contenders, seconds=seconds, command=command)
    lost_links = suite.name.startswith("dropout")
    if lost_links:  # the curve against p, before the notes
        markdown = markdown.replace("### Notes", dropout.dropout_section(results, contenders) + "\n\n### Notes")
    files = [
        report.write_text(markdown, out / "table.md"),
        report.write_csv(rows, out / "results.csv"),
        report.write_csv(report.episode_rows(results), out / "episodes.csv"),
        *figures.write_figures(results, suite, contenders, out),
        *([dropout.dropout_figure(results, contenders, out / "error_vs_dropout.png")] if lost_links else []),
    ]
    return BenchmarkOutput(markdown, files, results, seconds)


# ------------------------------------------------------------------------- CLI
def add_benchmark_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``benchmark`` subcommand to the ``fxc`` command line."""
    parser = subparsers.add_parser(
        "benchmark",
        help="score the reference, the baselines and learned policies on the same cases at T_s",
        description="Score the reference, the baselines and learned policies on identical seeded cases "
        "by the deadline metrics; write table.md, results.csv, episodes.csv and three PNGs.",
    )
    parser.add_argument("--quick", action="store_true", help="a smaller suite that runs in under a minute")
    parser.add_argument(
        "--suite",
        choices=("full", "realism", "models", "optimality", "dropout"),
        default="full",
        help="'full': topologies x sizes x budgets; 'realism': input limits, noise and dropout; 'models': every "
        "agent model (single, double, triple, quadruple integrators, damped, oscillator) at K = 200, 400; "
        "'optimality': error, energy / E* and intervals used against the radius and all-roots bounds (rings and random "
        "digraphs N = 20, 100, paper_fig1, K = 200, reference, minimum_time and signalling on both schedules); "
        "'dropout': what a lost link costs the laws that claim exactness (their allow_dropout opt-ins and the reference "
        "on a ring and a random digraph of 20 at link_dropout 1e-4 to 1e-1, K = 200)",
    )
    parser.add_argument("--out", default="out/benchmark", help="directory for table.md, CSVs and PNGs")
    parser.add_argument("--seeds", type=int, default=20, help="seeded initial states per case")
    parser.add_argument("--workers", type=int, help="processes, or a local Ray's cores with --ray (default: all cores)")
    parser.add_argument(
        "--ray",
        action="store_true",
        help="run the jobs as Ray tasks: on a local Ray, or on the cluster at --address (needs fxc-env[rllib])",
    )
    parser.add_argument(
        "--address",
        help="with --ray: the Ray cluster to join (auto, or HOST:6379); every node needs fxc-env, and "
        "learned policies at the same path",
    )
    _add_contender_arguments(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(handler=benchmark_command)
    return parser


def _add_contender_arguments(parser: argparse.ArgumentParser) -> None:
    """``fxc benchmark``'s flags that choose the contenders and a learned policy's settings."""
    parser.add_argument("--fine-intervals", type=int, help="K of continuous laws (default 4000; 1000 with --quick)")
    parser.add_argument("--policies", help="comma-separated built-in policies (default: reference and every baseline)")
    parser.add_argument(
        "--obs-resolution",
        type=float,
        help="also run every case without conditions with rows rounded to this quantum (m, m/s), beside its "
        "resolution floor",
    )
    parser.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="PATH",
        help="a saved SB3 model (PPO or SAC .zip), a torch policy (policy.pt or its run directory), a gain schedule "
        "(.npz), an RLlib checkpoint or run directory, or 'pretrained' "
        "for the one shipped with fxc_env, to score as well; repeatable",
    )
    add_policy_file_flags(parser)
    parser.add_argument(
        "--learned-schedule",
        choices=("paper", "uniform"),
        help="schedule of learned policies (default: the one a shipped policy was trained on, else paper)",
    )
    parser.add_argument(
        "--learned-action-mode", default="plan", choices=("plan", "accel"), help="action mode of learned policies"
    )
    parser.add_argument(
        "--learned-obs-mode",
        default="normalized",
        choices=("normalized", "raw"),
        help="observation mode of learned policies",
    )


def add_policy_file_flags(parser: argparse.ArgumentParser) -> None:
    """``--trust-policy-file`` and ``--allow-out-of-domain``: what ``fxc benchmark`` and ``fxc evaluate`` may load."""
    parser.add_argument(
        "--trust-policy-file",
        action="store_true",
        help="allow saved policies whose format must unpickle (RLlib checkpoints, SB3 zips without fxc_policy.json, "
        "VecNormalize .pkl): unpickling runs code from the file, so only for files you made or trust",
    )
    parser.add_argument(
        "--allow-out-of-domain",
        action="store_true",
        help="run learned policies on cases outside the training domain their files record (graphs, N, switching, "
        "schedule, K, ...), with a warning naming every difference; without it such cases are reported as not run",
    )


def make_out(out: Path) -> None:
    """Create the output directory ``--out`` (checked earlier by ``output_directory``), or refuse naming it."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a read-only file system, which os.access does not see for root
        raise ArgumentError(f"--out: cannot create {str(out)!r} ({exc.strerror or exc})") from exc


def refuse_unrun_policy(flag: str, contender: str, results: list[Any]) -> None:
    """Refuse (naming ``flag`` and the first reason) a learned ``contender`` that every case of the suite refused."""
    own = [result for result in results if result.job.contender.name == contender]
    if own and all(result.error is not None for result in own):
        raise ArgumentError(f"{flag}: {contender} could not run on any case of the suite ({own[0].error})")


def _checked_out(args: argparse.Namespace) -> Any:
    """``fxc benchmark``'s numeric and Ray flags checked (one-line errors naming each); its ``--out`` folder."""
    integer("--seeds", args.seeds, 1)
    if args.workers is not None:
        integer("--workers", args.workers, 1)
    if args.fine_intervals is not None:
        integer("--fine-intervals", args.fine_intervals, 1, MAX_INTERVALS)
    if args.address is not None and not args.ray:
        raise ArgumentError("--address: joins a Ray cluster for --ray; add --ray")
    if args.address is not None and args.workers is not None:
        raise ArgumentError("--workers: sets the cores of a local Ray; the cluster at --address has its own")
    return output_directory("--out", args.out)


def benchmark_command(args: argparse.Namespace) -> int:
    """Handler of ``fxc benchmark``: run, print the Markdown report, list the files."""
    # Every value is checked (and every learned policy loaded) before the first job runs.
    out = _checked_out(args)
    names = _policy_names(args)
    suites = {"full": full_suite, "realism": realism_suite, "models": models_suite}
    if args.suite == "optimality":
        make_suite = quick_optimality_suite if args.quick else optimality_suite
    elif args.suite == "dropout":
        make_suite = dropout.quick_dropout_suite if args.quick else dropout.dropout_suite
    else:
        make_suite = quick_suite if args.quick else suites[args.suite]
    suite = make_suite(args.seeds, **({"fine_intervals": args.fine_intervals} if args.fine_intervals else {}))
    suite = with_resolution(suite, args.obs_resolution)
    if names is None and args.suite == "models":
        names = ["reference"]  # the analytic baselines are the double integrator's laws
    if names is None and args.suite == "optimality":
        contenders = optimality_contenders()  # the reference, minimum_time and signalling on both schedules
    elif names is None and args.suite == "dropout":
        contenders = dropout.dropout_contenders()  # the reference and every exact law's allow_dropout opt-in
    else:
        contenders = builtin_contenders(names)
    for spec in args.policy:
        contenders.append(
            learned_contender(
                spec,
                schedule=args.learned_schedule,
                action_mode=args.learned_action_mode,
                obs_mode=args.learned_obs_mode,
                name="--policy",
                trusted=args.trust_policy_file,
                allow_out_of_domain=args.allow_out_of_domain,
            )
        )
    command = "fxc benchmark " + " ".join(sys.argv[2:]) if sys.argv[1:2] == ["benchmark"] else None
    make_out(out)
    output = run_benchmark(
        suite,
        contenders,
        out,
        workers=args.workers,
        progress=not args.no_progress,
        command=command,
        ray=args.ray,
        address=args.address,
    )
    print(output.markdown)
    print("wrote " + ", ".join(str(f) for f in output.files))
    print(f"benchmark wall time: {output.seconds:.1f} s")
    for learned in contenders[len(contenders) - len(args.policy) :]:  # a --policy no case could run
        refuse_unrun_policy("--policy", learned.name, output.results)
    return 0


def _policy_names(args: argparse.Namespace) -> list[str] | None:
    """``--policies`` as names of :data:`~fxc_env.baselines.registry.LAWS` (None: not given)."""
    names = None if args.policies is None else [n.strip() for n in args.policies.split(",") if n.strip()]
    if names is not None:
        unknown = [n for n in names if n not in LAWS]
        if unknown:
            raise ArgumentError(f"--policies: unknown name(s) {unknown}; expected some of {tuple(LAWS)}")
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ArgumentError(f"--policies: {twice[0]!r} is named twice in {args.policies!r}")
        if not names and not args.policy:
            raise ArgumentError(f"--policies: expected at least one of {tuple(LAWS)} (or a --policy)")
    return names
