"""``fxc evaluate``: a learned policy next to the reference on the deadline benchmark.

The suite: the paper's example plus directed ``ring``, ``path`` and ``random`` at N = 20, 20 seeded initial
states each, at K = 200; tables and plots are the benchmark's (:mod:`fxc_env.baselines.harness.benchmark`).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from typing import Any

from fxc_env.baselines.harness.benchmark import add_policy_file_flags, make_out, refuse_unrun_policy, run_benchmark
from fxc_env.baselines.harness.suite import (
    BenchmarkCase,
    Contender,
    Suite,
    builtin_contenders,
    generalisation_suite,
    learned_contender,
    realism_suite,
)
from fxc_env.config import make_config
from fxc_env.config.flags import add_env_arguments, env_kwargs_from
from fxc_env.config.scenarios import scenario_preset
from fxc_env.config.tasks import TASKS, NamedTask, get_task
from fxc_env.core.models import MODEL_PARAMETERS
from fxc_env.core.validation import ArgumentError, integer, optional_seed
from fxc_env.training.evaluation import seed_evaluation
from fxc_env.training.evaluation.statistics import DEFAULT_BOOTSTRAP_SEED, DEFAULT_REPS
from fxc_env.utils.cli_checks import budgets as parse_budgets
from fxc_env.utils.cli_checks import output_directory

EVALUATION_CASES = (
    BenchmarkCase("paper_fig1", 6),
    BenchmarkCase("ring", 20),
    BenchmarkCase("path", 20),
    BenchmarkCase("random", 20),
)


def evaluation_suite(n_seeds: int = 20, budgets: tuple[int, ...] = (200,)) -> Suite:
    """``paper_fig1`` and the N = 20 generalisation graphs, seeds ``0 .. n_seeds - 1``."""
    return Suite(
        cases=EVALUATION_CASES,
        seeds=tuple(range(n_seeds)),
        budgets=budgets,
        fine_intervals=1000,
        headline_budget=max(budgets) if 200 not in budgets else 200,
        name="evaluate",
    )


SUITES = ("evaluate", "generalisation", "realism")

#: The flags a named task fixes (its settings, K and evaluation seeds): refused beside ``--task``.
TASK_FIXES = ("--suite", "--seeds", "--budgets")


def scored_settings(task: NamedTask) -> dict[str, Any]:
    """The settings of a task's scored episodes: its scenario's preset spelled out, without a fixed initial
    state (each evaluation seed draws its own, for every contender alike; docs: tasks/index.md, "Named tasks")."""
    kwargs = task.kwargs()
    kwargs = {**scenario_preset(kwargs.pop("scenario", None)), **kwargs}
    kwargs.pop("initial_state", None)
    return kwargs


def task_suite(task: NamedTask) -> tuple[Suite, dict[str, Any]]:
    """The one case of a named task at its K, on its evaluation seeds (every setting of its scenario's preset
    spelled out); and its learned policies' settings."""
    kwargs = scored_settings(task)
    n_intervals = kwargs.pop("n_intervals")
    learned = {k: kwargs.pop(k) for k in ("action_mode", "obs_mode", "schedule") if k in kwargs}
    case, settling_time = custom_case(kwargs)
    suite = Suite(
        cases=(case,),
        seeds=task.eval_seeds,
        budgets=(n_intervals,),
        fine_intervals=1000,
        settling_time=settling_time,
        headline_budget=n_intervals,
        trace_case=case,
        name=task.id,
    )
    return suite, learned


def on_task_schedule(contenders: list[Contender], learned: dict[str, Any]) -> list[Contender]:
    """``contenders`` as a task scores them: where the task fixes a schedule (``learned["schedule"]``, e.g. the
    saturated tasks' uniform one), every contender runs on it, the reference included, since the task is one
    environment; elsewhere each keeps its own."""
    schedule = learned.get("schedule")
    return contenders if schedule is None else [replace(c, schedule=schedule) for c in contenders]


def add_evaluate_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``fxc evaluate``."""
    parser = commands.add_parser(
        "evaluate",
        help="score a learned policy next to the reference on a named suite or on any environment setting",
        description="Score a policy next to the reference (at the same K and seeds) on a named suite "
        "(default 'evaluate': paper_fig1 and N=20 ring, path, random; 'generalisation': families and sizes "
        "drawn per episode; 'realism': input limits, noise, dropout), or, when environment flags are given, "
        "on that one environment.",
    )
    parser.add_argument(
        "--policy",
        help="'reference', 'pretrained' (shipped with fxc_env), the path of a saved SB3 model (.zip), "
        "a torch policy (policy.pt or its run directory: fxc train --backend torch), a gain schedule (.npz), "
        "or an RLlib checkpoint or run directory (fxc train --backend rllib)",
    )
    parser.add_argument(
        "--runs",
        nargs="+",
        metavar="RUN",
        help="instead of --policy: one policy's training seeds (run directories, saved policies, shipped names, "
        "globs such as 'runs/x-seed*', or a folder of *-seed<k> runs); adds the median and IQM over seeds with 95%% "
        "bootstrap intervals (seeds.md, seeds.json) and marl_eval.json",
    )
    parser.add_argument("--label", help="with --runs: the policy's name in the tables (default: the runs' name)")
    parser.add_argument(
        "--bootstrap-reps", type=int, default=DEFAULT_REPS, help=f"with --runs: bootstrap replicates ({DEFAULT_REPS})"
    )
    parser.add_argument(
        "--bootstrap-seed",
        type=int,
        default=DEFAULT_BOOTSTRAP_SEED,
        help=f"with --runs: seed of the bootstrap's generator ({DEFAULT_BOOTSTRAP_SEED}; fixed, so reruns agree)",
    )
    add_policy_file_flags(parser)
    parser.add_argument("--suite", choices=SUITES, help="a named suite (default 'evaluate' without environment flags)")
    parser.add_argument(
        "--task",
        help=f"a named, versioned task ({', '.join(TASKS)}; 'fxc/' prefix optional): its settings, K and "
        "evaluation seeds, as BenchMARL and PettingZoo know it",
    )
    parser.add_argument("--seeds", type=int, help="seeded episodes per case (default 20)")
    parser.add_argument("--budgets", help="comma-separated K values (default 200)")
    parser.add_argument("--out", default="out/evaluate", help="directory for table.md, CSVs and PNGs")
    parser.add_argument("--workers", type=int, help="processes (default: one per core)")
    parser.add_argument("--baselines", action="store_true", help="score the four baseline laws as well")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_env_arguments(parser, scenario_default=None)
    parser.set_defaults(handler=evaluate_command)


def custom_case(env_kwargs: dict[str, Any]) -> tuple[BenchmarkCase, float]:
    """The one case that environment flags describe, and its ``T_s``; validated by building its config."""
    config = make_config(**env_kwargs)
    given = {k: v for k, v in env_kwargs.items() if k not in ENV_FIELDS_OF_CONTENDERS and k != "scenario"}
    conditions = []
    for name in ("u_max", "obs_noise", "link_dropout", "switching", "position_range", "velocity_range"):
        if name in given or (name == "u_max" and config.u_max_choices is not None):
            value = config.u_max_choices if name == "u_max" else getattr(config, name)
            conditions.append((name, value[0] if isinstance(value, tuple) and len(set(value)) == 1 else value))
    if config.formation is not None:
        raise ArgumentError(
            "--scenario: fxc evaluate scores consensus cases; formation offsets (formation scenarios) are not "
            "carried into its cases, so a formation is refused rather than scored as plain consensus"
        )
    if config.agent_model != "double_integrator":
        # The agent model and its parameter, as the models suite carries them (docs: agent-models.md, "Agent models and formations").
        conditions.append(("agent_model", config.agent_model))
        spec = env_kwargs.get("agent_model")
        given = {**given, **spec} if isinstance(spec, dict) else given  # the spec's parameter, or a flat alias
        conditions += [(name, given[name]) for name in MODEL_PARAMETERS.values() if given.get(name) is not None]
    topology = config.family if config.family is not None else config.topology
    return BenchmarkCase(topology, config.n_agents, conditions=tuple(conditions), dim=config.dim), config.settling_time


#: Settings that belong to each contender (its schedule, K, modes, width), not to the case.
ENV_FIELDS_OF_CONTENDERS = ("n_intervals", "schedule", "action_mode", "obs_mode", "obs_slots")


def evaluate_command(args: argparse.Namespace) -> int:
    """Handler of ``fxc evaluate``: every value is checked (and the policy loaded) before the suite runs."""
    task = _checked_task(args)
    seeds = integer("--seeds", 20 if args.seeds is None else args.seeds, 1)
    budgets = parse_budgets("--budgets", "200" if args.budgets is None else args.budgets)
    if args.workers is not None:
        integer("--workers", args.workers, 1)
    out = output_directory("--out", args.out)
    suite, learned = _evaluation_suite(args, task, seeds, budgets)
    contenders = builtin_contenders(None if args.baselines else ["reference"])
    if task is not None:
        contenders = on_task_schedule(contenders, learned)
    runs: list[Any] = []
    if args.runs is not None:
        runs = [seed_evaluation.resolve_run(entry) for entry in seed_evaluation.expand_runs(args.runs)]
        label = args.label or seed_evaluation.default_label(runs)
        own = seed_evaluation.seed_contenders(
            runs, label, trusted=args.trust_policy_file, allow_out_of_domain=args.allow_out_of_domain, **learned
        )
        contenders += own
    elif args.policy != "reference":
        trust = {"trusted": args.trust_policy_file, "allow_out_of_domain": args.allow_out_of_domain}
        contenders.append(learned_contender(args.policy, name="--policy", **trust, **learned))
    command = "fxc " + " ".join(sys.argv[1:]) if sys.argv[1:2] == ["evaluate"] else None
    make_out(out)
    output = run_benchmark(suite, contenders, out, workers=args.workers, progress=not args.no_progress, command=command)
    print(output.markdown)
    files = list(output.files)
    if runs:
        scores = seed_evaluation.case_scores(output.results, suite, own, runs)
        table, written = seed_evaluation.write_seed_report(
            out, scores, runs, label, reps=args.bootstrap_reps, seed=args.bootstrap_seed, command=command
        )
        print(f"\n{label} over training seeds {', '.join(str(r.seed) for r in runs)} (95% stratified bootstrap):\n")
        print(table)
        files += written
    print("wrote " + ", ".join(str(f) for f in files))
    for contender in own if runs else contenders[-1:] if args.policy != "reference" else ():
        refuse_unrun_policy("--runs" if runs else "--policy", contender.name, output.results)
    return 0


def _checked_task(args: argparse.Namespace) -> NamedTask | None:
    """``--policy`` or ``--runs`` with the flags only ``--runs`` reads, the bootstrap's; the ``--task`` named."""
    if (args.policy is None) == (args.runs is None):
        raise ArgumentError("--policy: give one policy (--policy) or the training seeds of one (--runs)")
    if args.runs is None:
        for flag, value, default in (
            ("--label", args.label, None),
            ("--bootstrap-reps", args.bootstrap_reps, DEFAULT_REPS),
            ("--bootstrap-seed", args.bootstrap_seed, DEFAULT_BOOTSTRAP_SEED),
        ):
            if value != default:
                raise ArgumentError(f"{flag}: only --runs reads it (several training seeds), not --policy")
    integer("--bootstrap-reps", args.bootstrap_reps, 1)
    optional_seed("--bootstrap-seed", args.bootstrap_seed)
    task = None if args.task is None else get_task(args.task, "--task")
    for flag in TASK_FIXES if task is not None else ():
        if getattr(args, flag[2:]) is not None:
            raise ArgumentError(f"{flag}: --task {task.id} fixes its settings, K and evaluation seeds; leave it out")
    return task


def _evaluation_suite(
    args: argparse.Namespace, task: NamedTask | None, seeds: int, budgets: tuple[int, ...]
) -> tuple[Suite, dict[str, Any]]:
    """The suite the flags ask for, and the learned policy's own settings (schedule, modes) among them."""
    custom = {k: v for k, v in env_kwargs_from(args).items() if v is not None}
    if custom and args.suite is not None:
        raise ArgumentError("--suite: give a named suite or environment flags, not both")
    if custom and task is not None:
        flag = "--" + next(iter(custom)).replace("_", "-")
        raise ArgumentError(f"{flag}: --task {task.id} fixes the environment's settings; leave the flag out")
    if custom:
        make_config(**custom)  # every flag together, through the Python API's checks (docs: bad-input.md)
    # The learned policy's own settings (the reference keeps its schedule and modes).
    learned = {k: custom.pop(k) for k in ("action_mode", "obs_mode", "schedule") if k in custom}
    if learned and args.policy == "reference":
        flag = "--" + next(iter(learned)).replace("_", "-")
        raise ArgumentError(
            f"{flag}: sets a learned policy's setting (--policy FILE or --runs); the reference keeps its own "
            "schedule and modes, so leave it out with --policy reference"
        )
    if "n_intervals" in custom:
        raise ArgumentError("--n-intervals: the budgets K come from --budgets")
    if task is not None:
        return task_suite(task)
    if custom:
        case, settling_time = custom_case(custom)
        named = replace(evaluation_suite(seeds, budgets), cases=(case,), trace_case=case, name="custom")
        return replace(named, settling_time=settling_time), learned
    if args.suite == "generalisation":
        return generalisation_suite(seeds, budgets), learned
    if args.suite == "realism":
        headline = 200 if 200 in budgets else max(budgets)
        return replace(realism_suite(seeds), budgets=budgets, headline_budget=headline), learned
    return evaluation_suite(seeds, budgets), learned
