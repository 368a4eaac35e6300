"""The ``fxc`` command line: ``fxc simulate`` runs a scenario and writes its figures.

Every subcommand parses with argparse and checks all of its paths, counts and thresholds
(:mod:`fxc_env.utils.cli_checks`) before it starts work. A usage error is an
:class:`~fxc_env.core.validation.ArgumentError` (the only exception :func:`main` turns into
``fxc <command>: error: <message>`` on stderr, exit status 2); any other exception is a bug
and keeps its traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from typing import Any

from fxc_env.analysis.video import add_video_arguments
from fxc_env.baselines.harness.benchmark import add_benchmark_parser, make_out
from fxc_env.config.argument_types import FlagParser
from fxc_env.config.flags import add_env_arguments, env_kwargs_from
from fxc_env.core.validation import ArgumentError, integer, optional_seed
from fxc_env.speed.command import add_arguments as speed_arguments
from fxc_env.training.args import add_train_parser
from fxc_env.training.evaluation.evaluate import add_evaluate_parser
from fxc_env.training.evaluation.leaderboard import add_leaderboard_parser
from fxc_env.utils.cli_checks import output_directory

#: The usage error: the one exception :func:`main` prints as a one-line message (exit status 2).
UsageError = ArgumentError


def _format(value: float) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.15g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.3e}"


def simulate_command(args: argparse.Namespace) -> int:
    from fxc_env.analysis.plots import write_figures
    from fxc_env.analysis.simulation import simulate
    from fxc_env.analysis.video import video_request, write_video

    out = output_directory("--out", args.out)
    video = video_request(args)
    integer("--points-per-interval", args.points_per_interval, 1)
    optional_seed("--seed", args.seed)
    kwargs = env_kwargs_from(args)
    scenario = kwargs.pop("scenario")
    trajectory = simulate("reference", scenario, seed=args.seed, points_per_interval=args.points_per_interval, **kwargs)
    c, topology = trajectory.config, trajectory.topology
    make_out(out)
    files = write_figures(trajectory, out)
    xi = topology.consensus_weights() if c.n_agents <= 2000 and c.switching == "periodic" else None
    (out / "metrics.json").write_text(
        json.dumps(_simulate_record(trajectory, scenario, args.seed, xi), indent=2) + "\n"
    )
    files.append(out / "metrics.json")
    if video is not None:
        title = f"{scenario or 'custom'}: reference policy"
        drawn = write_video(trajectory, video[0], video[2], strip=video[1], title=title)
        files += [path for path in (drawn.video, drawn.strip) if path is not None]
    _print_simulation(trajectory, scenario, xi)
    if video is not None:
        width, height = drawn.size
        print(
            f"\nvideo: {drawn.n_frames} frames of {width}x{height} px, uniform in t from 0 to T_s, {drawn.fps} frames/s; "
            f"drawn at {drawn.draw_rate:.1f} frames/s"
        )
    print("\nwrote " + ", ".join(str(f) for f in files))
    return 0


def _simulate_record(trajectory: Any, scenario: str | None, seed: int | None, xi: Any) -> dict[str, Any]:
    """``metrics.json`` of ``fxc simulate``: the settings, the consensus weights and the metrics."""
    c, topology = trajectory.config, trajectory.topology
    settings = {"topology": topology.describe(), "topology_note": topology.note}
    settings.update({key: getattr(c, key) for key in ("n_agents", "n_intervals", "settling_time")})
    settings.update(schedule=c.schedule.name, dim=c.dim, agent_model=c.agent_model, n_states=c.n_states)
    settings["formation_offsets"] = None if c.formation is None else c.formation.tolist()
    settings.update(action_mode=c.action_mode, obs_mode=c.obs_mode, seed=seed, u_max=trajectory.u_max)
    settings["edges"] = [edges.tolist() for edges in topology.edges]
    return {
        "scenario": scenario,
        "settings": settings,
        "xi": None if xi is None else xi.tolist(),
        "metrics": trajectory.metrics.as_dict(),
    }


def _table(header: tuple[str, str, str], rows: list[tuple[str, Any, Any]]) -> None:
    """A three-column Markdown table; numbers as :func:`_format` writes them."""
    text = [
        (name, b if isinstance(b, str) else _format(b), c if isinstance(c, str) else _format(c)) for name, b, c in rows
    ]
    print(f"\n| {header[0]:<38} | {header[1]:>22} | {header[2]:>22} |")
    print(f"|{'-' * 40}|{'-' * 24}|{'-' * 24}|")
    for name, b, c in text:
        print(f"| {name:<38} | {b:>22} | {c:>22} |")


def _print_simulation(trajectory: Any, scenario: str | None, xi: Any) -> None:
    """The settings, the metrics against the prediction and how far from optimal (docs: optimality.md) the reference was."""
    c, m, topology = trajectory.config, trajectory.metrics, trajectory.topology
    print(f"fxc simulate: {scenario or 'custom'} — {topology.describe()}")
    if topology.note:
        print(f"  topology: {topology.note}")
    print(f"  T_s = {c.settling_time:g} s, K = {c.n_intervals} intervals ({c.schedule.name} schedule), dim = {c.dim}")
    if c.model is not None or c.formation is not None:
        shape = "" if c.formation is None else ", formation offsets (agreement on z_i - e^(At) h_i)"
        print(f"  agents: {c.agent_model} (n = {c.n_states} states per axis){shape}")
    if xi is not None:
        print("  xi = [" + ", ".join(f"{w:.6g}" for w in xi) + "]")
    rows = [
        ("x*(T_s): mean position", m.predicted_final_position, m.achieved_final_position),
        ("v*: mean velocity", m.predicted_final_velocity, m.achieved_final_velocity),
        ("relative deadline error D(T_s)/D(0)", "", m.relative_deadline_error),
        ("position spread e_x(T_s) (m)", "", m.final_position_spread),
        ("velocity spread e_v(T_s) (m/s)", "", m.final_velocity_spread),
        ("t_eps, eps = 1e-2 (s)", "", m.t_eps_1e_2),
        ("t_eps, eps = 1e-6 (s)", "", m.t_eps_1e_6),
        ("energy sum_i ∫ u_i² dt (m²/s³)", "", m.energy),
        ("peak abs(u) (m/s²)", "", m.peak_input),
        ("sampling instants K", "", float(m.sampling_instants)),
    ]
    _table(("quantity", "predicted (xi)", "achieved"), rows)
    bounds = [
        ("energy (m²/s³), any law", m.energy_bound, m.energy),
        ("energy / E*, any law", 1.0, m.energy_ratio),
        ("intervals to 1e-9, any law (radius)", m.radius_bound, m.settled_interval),
        ("intervals, laws using every root", m.all_roots_bound, m.settled_interval),
    ]
    if m.noise_floor == m.noise_floor:  # under obs_noise (NaN otherwise)
        bounds.append(("D(T_s)/D(0) under the noise", m.noise_floor, m.relative_deadline_error))
    if m.resolution_floor == m.resolution_floor:  # under obs_resolution: the worst case of states reading 0
        bounds.append(("D(T_s)/D(0), worst silent state", m.resolution_floor, m.relative_deadline_error))
    if m.input_floor == m.input_floor:  # under u_max: the least limit of exact consensus, beside the limit run
        bounds.append(("u_max of exact consensus (m/s²)", m.input_floor, f"u_max = {trajectory.u_max:g}"))
    _table(("how far from optimal", "lower bound", "reference"), bounds)


def speed_command(args: argparse.Namespace) -> int:
    from fxc_env.speed import command as speed
    from fxc_env.utils.threads import pin_threads_or_reexec

    speed.check_arguments(args)
    pin_threads_or_reexec("fxc_env.cli", sys.argv[1:] if args.argv is None else args.argv)
    return speed.run(args)


def train_command(args: argparse.Namespace) -> int:
    """``fxc train``: the back end named by ``--backend`` trains (see :mod:`fxc_env.training.backends`).

    Every flag is checked before work starts (``--backend torchrl`` is read as ``--backend torch``,
    with a deprecation message on stderr); Ctrl-C saves a checkpoint and exits with status 130.
    ``--seeds`` trains one run per seed, in turn (:mod:`fxc_env.training.evaluation.seeds`).
    """
    from fxc_env.training.args import args_from_namespace, check_train_args
    from fxc_env.training.backends import train
    from fxc_env.training.evaluation.seeds import seed_flag_given, train_seeds

    train_args = args_from_namespace(args)
    if train_args.seeds is not None and seed_flag_given(args):
        raise UsageError("--seeds: give one seed (--seed) or several (--seeds), not both")
    if train_args.task is not None and "scenario" in getattr(args, "given_flags", ()):
        raise UsageError(f"--scenario: --task {train_args.task} sets the environment; leave out --scenario")
    try:
        if train_args.seeds is not None:
            train_seeds(train_args, flags=True)  # every seed is checked before any trains
        else:
            check_train_args(train_args, flags=True)
            train(train_args)
    except KeyboardInterrupt:
        return 130
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = FlagParser(prog="fxc", description="Fixed-time consensus of double integrators (fxc_env).")
    commands = parser.add_subparsers(dest="command", required=True)
    sim = commands.add_parser("simulate", help="run the reference policy on a scenario and write figures")
    add_env_arguments(sim)
    sim.add_argument("--seed", type=int, default=0, help="seed of the episode (initial state, family draw, noise)")
    sim.add_argument("--out", default="out", help="directory for PNGs and metrics.json")
    sim.add_argument("--points-per-interval", type=int, default=24, help="dense samples per interval in the figures")
    add_video_arguments(sim)
    sim.set_defaults(handler=simulate_command)
    fast = commands.add_parser("speed", help="throughput against MPE2 and VMAS, and scaling to 10^6 agents")
    speed_arguments(fast)
    fast.set_defaults(handler=speed_command, argv=None)
    add_train_parser(commands).set_defaults(handler=train_command)
    add_evaluate_parser(commands)
    add_leaderboard_parser(commands)
    add_benchmark_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if argv is not None and hasattr(args, "argv"):
        args.argv = list(argv)
    try:
        return args.handler(args)
    except UsageError as exc:  # only usage errors: any other exception is a bug and keeps its traceback
        message = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())  # one line
        print(f"fxc {args.command}: error: {message}", file=sys.stderr)
        return 2
