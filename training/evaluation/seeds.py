"""``fxc train --seeds``: one run per training seed, in turn, each in its own run directory.

``--seeds 0-4``, ``--seeds 0,2,5`` or ``0-2,7`` train the same run once per seed, one after another, on any
back end. Run directories: ``<--run-dir>-seed<k>``, else each seed's default
(``runs/<scenario>-[<backend>-]<algo>-seed<k>``). With ``--resume`` each directory goes on by itself (finished,
resumed or started afresh, said on stdout); every seed's arguments and resume checks are made before the
first one trains.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

from fxc_env.core.validation import ArgumentError
from fxc_env.training.args import TrainArgs, check_train_args, default_run_dir
from fxc_env.training.backends import train
from fxc_env.training.run_dir import RunDir

#: Most seeds one ``--seeds`` may name (each is a whole training run).
MAX_SEEDS = 1000
#: Largest seed (SB3 seeds numpy's legacy generator, which takes 32 bits).
MAX_TRAIN_SEED = 2**32 - 1


def parse_seeds(text: object, name: str = "--seeds") -> tuple[int, ...]:
    """The seeds ``text`` names: comma-separated integers and ``a-b`` ranges (``0-4``, ``0,2,5``, ``0-2,7``).

    Refused, naming ``name``: text that is not such a list, a range whose end is below its start,
    a seed named twice, seeds outside ``[0, 2**32)``, and more than :data:`MAX_SEEDS` seeds.
    """
    if not isinstance(text, str) or not text.strip():
        raise ArgumentError(f"{name}: expected seeds such as '0-4' or '0,2,5', got {text!r}")
    seeds: list[int] = []
    for part in text.split(","):
        piece = part.strip()
        low, dash, high = piece.partition("-")
        if not (low.strip().isdigit() and (not dash or high.strip().isdigit())):
            raise ArgumentError(f"{name}: expected seeds such as '0-4' or '0,2,5' (integers >= 0), got {text!r}")
        first = int(low)
        last = int(high) if dash else first
        if last < first:
            raise ArgumentError(f"{name}: the range {piece!r} ends below its start")
        if last > MAX_TRAIN_SEED:
            raise ArgumentError(f"{name}: seeds are integers in [0, 2**32), got {last}")
        if len(seeds) + last - first + 1 > MAX_SEEDS:
            raise ArgumentError(f"{name}: at most {MAX_SEEDS} seeds (each is a training run), got more in {text!r}")
        seeds.extend(range(first, last + 1))
    repeated = sorted({s for s in seeds if seeds.count(s) > 1})
    if repeated:
        raise ArgumentError(f"{name}: seed {repeated[0]} is named twice in {text!r}")
    return tuple(seeds)


def seed_run_dir(args: TrainArgs, seed: int) -> str:
    """The run directory of ``seed``: ``<run_dir>-seed<seed>``, or the seed's default without ``run_dir``."""
    if args.run_dir is not None:
        return f"{args.run_dir}-seed{seed}"
    return default_run_dir(dataclasses.replace(args, seed=seed, seeds=None, run_dir=None))


@dataclass(frozen=True)
class SeedRun:
    """One training seed of a sweep: its arguments and what it will do (``train``, ``resume``, ``done``)."""

    args: TrainArgs
    action: str
    note: str = ""


def plan_seed_runs(args: TrainArgs, *, flags: bool = True) -> list[SeedRun]:
    """Every seed of ``args.seeds`` as a checked single-seed run (see the module), before any trains.

    Raises :class:`~fxc_env.core.validation.ArgumentError` naming the flag (with ``flags``) or
    field for a bad ``--seeds`` or any seed's bad arguments, run directory or resume checks.
    """
    seeds = parse_seeds(args.seeds, "--seeds" if flags else "seeds")
    planned = []
    for seed in seeds:
        one = dataclasses.replace(args, seed=seed, seeds=None, run_dir=seed_run_dir(args, seed))
        run = RunDir.of(one)
        checkpoint = run.newest_checkpoint() if args.resume else None
        if args.resume and checkpoint is None:
            one = dataclasses.replace(one, resume=False, trust_policy_file=False)  # nothing to read
        check_train_args(one, flags=flags)
        if checkpoint is None:
            planned.append(SeedRun(one, "train", "no checkpoint yet, so it starts afresh" if args.resume else ""))
            continue
        steps = run.checkpoint_steps(checkpoint)
        if steps is not None and steps >= one.timesteps:
            planned.append(SeedRun(one, "done", f"already at {steps} timesteps ({checkpoint.name})"))
            continue
        run.resume_checkpoint(True, one)  # scenario and critic as the run started
        planned.append(SeedRun(one, "resume", f"from {checkpoint.name}"))
    return planned


def train_seeds(args: TrainArgs, *, flags: bool = False) -> list[Path]:
    """Train every seed of ``args.seeds`` in turn (see the module); returns their run directories.

    All seeds are checked first (:func:`plan_seed_runs`). Ctrl-C during one seed saves its
    checkpoint (as a single run does) and stops the sweep: ``KeyboardInterrupt`` propagates.
    """
    planned = plan_seed_runs(args, flags=flags)
    directories = []
    for i, seed_run in enumerate(planned, start=1):
        one = seed_run.args
        head = f"fxc train: seed {one.seed} ({i} of {len(planned)}) in {one.run_dir}"
        print(head + (f": {seed_run.note}" if seed_run.note else ""), flush=True)
        if seed_run.action != "done":
            train(one)
        directories.append(Path(one.run_dir))
    print(
        "fxc train: trained seeds "
        + ", ".join(str(r.args.seed) for r in planned)
        + " in "
        + ", ".join(str(d) for d in directories)
    )
    return directories


def seed_flag_given(namespace: argparse.Namespace) -> bool:
    """Whether ``--seed`` was on the command line (recorded by :func:`fxc_env.training.args.add_train_parser`)."""
    return "seed" in getattr(namespace, "given_flags", set())
