"""The run directory of ``fxc train``: what every back end writes besides its algorithm's state.

    runs/<name>/config.json             the exact arguments and resolved hyperparameters (:meth:`RunDir.start`)
    runs/<name>/versions.json           Python and library versions (:func:`versions`)
    runs/<name>/progress.csv            one row per rollout or iteration (:class:`Progress`; SB3's names)
    runs/<name>/events.out.tfevents.*   the same scalars for TensorBoard (sb3 and torch)
    runs/<name>/checkpoints/            one per save, named with its step count (:data:`CHECKPOINT_NAMES`)
    runs/<name>/training_curve.png      mean episode return against timesteps (:func:`write_training_curve`)

Resuming runs no code from the run directory unless the user passes ``--trust-policy-file``
(:data:`TRAIN_TRUST_HINT`); what only unpickling can read is refused without it, naming it (docs: training.md,
"Training learned policies").
"""

from __future__ import annotations

import csv
import dataclasses
import json
import platform
import re
import signal
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError
from fxc_env.training import registry
from fxc_env.training.args import TrainArgs, canonical_backend, check_train_args, default_run_dir

#: Checkpoint names by back end (``{}``: the timesteps it was saved at). SB3's sits beside its
#: VecNormalize statistics (``model_vecnormalize_<steps>_steps.pkl``); RLlib's is a directory.
CHECKPOINT_NAMES = {name: backend.checkpoint for name, backend in registry.BACKENDS.items()}
#: The end of every refusal to read a run directory's file that only unpickling would read.
TRAIN_TRUST_HINT = (
    "nothing in it was run; pass --trust-policy-file (TrainArgs.trust_policy_file) only if you trust whoever "
    "wrote the run directory"
)


def versions() -> dict[str, str]:
    """Python and the versions of the libraries a run depends on (``not installed`` for those missing)."""
    found = {"python": platform.python_version()}
    for name in ("fxc-env", "numpy", "gymnasium", "pettingzoo", "stable-baselines3", "torch", "ray"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def begin_run(args: TrainArgs, backend: str) -> tuple[TrainArgs, dict[str, Any], RunDir, Path | None]:
    """A back end's first steps: every argument checked before any work, torch's threads set, the run directory
    and the checkpoint a resumed run goes on from (:meth:`RunDir.resume_checkpoint`)."""
    import torch

    args = dataclasses.replace(args, backend=backend)
    params = check_train_args(args)
    torch.set_num_threads(args.torch_threads)
    run = RunDir.of(args)
    return args, params, run, run.resume_checkpoint(args.resume, args)


class RunDir:
    """The run directory ``path`` of a ``backend`` (``sb3``, ``torch`` or ``rllib``; ``torchrl`` is read as ``torch``)."""

    def __init__(self, path: str | Path, backend: str) -> None:
        self.backend = canonical_backend(backend, warn=False)
        self.path = Path(path)
        self.checkpoints = self.path / "checkpoints"
        self.checkpoint_name = CHECKPOINT_NAMES[self.backend]
        prefix, suffix = self.checkpoint_name.split("{}")
        self._pattern = re.compile(re.escape(prefix) + r"(\d+)" + re.escape(suffix))

    @classmethod
    def of(cls, args: TrainArgs) -> RunDir:
        """The run directory of ``args``: ``--run-dir``, or :func:`~fxc_env.training.args.default_run_dir`."""
        return cls(args.run_dir or default_run_dir(args), args.backend)

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_path(self, timesteps: int) -> Path:
        """Where the checkpoint saved at ``timesteps`` goes (``checkpoints/model_<timesteps>_steps.zip`` for sb3)."""
        return self.checkpoints / self.checkpoint_name.format(int(timesteps))

    def checkpoint_steps(self, path: Path) -> int | None:
        """The timesteps in a checkpoint's name (None if ``path`` is not named as this back end's checkpoints)."""
        match = self._pattern.fullmatch(Path(path).name)
        return int(match.group(1)) if match else None

    def newest_checkpoint(self) -> Path | None:
        """The whole checkpoint with the most timesteps (None if there is none)."""
        marker = registry.BACKENDS[self.backend].complete  # a checkpoint directory is whole once it holds this
        found = [
            (steps, path)
            for path in self.checkpoints.glob(self.checkpoint_name.format("*"))
            if (steps := self.checkpoint_steps(path)) is not None and (marker is None or (path / marker).is_file())
        ]
        return max(found)[1] if found else None

    def resume_checkpoint(self, resume: bool, args: TrainArgs | None = None) -> Path | None:
        """The checkpoint a run goes on from: the newest with ``resume``, None without; ``resume`` and none is refused.

        With ``args``, a resumed run must keep ``config.json``'s ``backend``, ``scenario`` and ``critic`` and
        reach beyond the checkpoint's timesteps (what the checkpoint holds is checked as the back end reads it:
        :mod:`fxc_env.training.backends.checkpoint_checks`); an RLlib checkpoint is refused unless ``args.trust_policy_file``.
        """
        if not resume:
            return None
        checkpoint = self.newest_checkpoint()
        if checkpoint is None:
            expected = self.checkpoint_name.format("<timesteps>")
            raise ArgumentError(f"resume: no checkpoint in {self.checkpoints} (expected {expected})")
        if args is not None:
            if self.backend == "rllib" and not args.trust_policy_file:
                raise ArgumentError(
                    f"resume: {checkpoint} is an RLlib checkpoint, which RLlib restores by unpickling "
                    f"(running code from the files); {TRAIN_TRUST_HINT}"
                )
            self._check_resumed_args(checkpoint, args)
        return checkpoint

    def _check_resumed_args(self, checkpoint: Path, args: TrainArgs) -> None:
        config = self.path / "config.json"
        started = recorded_args(config)  # a damaged config.json: the checkpoint's own checks still apply
        for field in ("backend", "scenario", "task", "critic"):
            before, now = started.get(field), getattr(args, field)
            before = canonical_backend(before, warn=False) if field == "backend" else before
            recorded = before is not None or (field == "task" and "scenario" in started)  # a task run records both
            if recorded and before != now:
                raise ArgumentError(
                    f"{field}: the run in {self.path} was started with {field} {before!r} ({config.name}), "
                    f"so --resume goes on with {before!r}, not {now!r}"
                )
        steps = self.checkpoint_steps(checkpoint)
        if steps is not None and steps >= args.timesteps:
            raise ArgumentError(
                f"timesteps: the run in {self.path} is already at {steps} timesteps ({checkpoint.name}), "
                f"so --resume to {args.timesteps} has nothing to train; ask for more timesteps"
            )

    def announce_resume(self, checkpoint: Path, position: str) -> None:
        """``fxc train: resuming <run> from <checkpoint> at <position>`` on stdout."""
        print(f"fxc train: resuming {self.path} from {checkpoint.name} at {position}")

    # -------------------------------------------------------------------- the files
    def start(self, record: Mapping[str, Any]) -> None:
        """A fresh run: create the directory, write ``config.json`` (``record``) and ``versions.json``."""
        self.create()
        (self.path / "config.json").write_text(json.dumps(record, indent=2) + "\n")
        (self.path / "versions.json").write_text(json.dumps(versions(), indent=2) + "\n")

    def create(self) -> None:
        """Create the run directory (``mkdir -p``).

        A place this process cannot write is refused as ``run_dir``, naming the path.
        """
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ArgumentError(f"run_dir: cannot create {str(self.path)!r} ({exc.strerror or exc})") from exc

    def progress(
        self, columns: Sequence[str], *, tensorboard: bool, resumed_at: tuple[int, int] | None = None
    ) -> Progress:
        """The log of this run (see :class:`Progress`); use it as a context manager."""
        return Progress(self.path, columns, tensorboard=tensorboard, resumed_at=resumed_at)

    def sb3_logger(self, resumed_at: int | None = None) -> Any:
        """SB3's logger writing ``progress.csv`` and TensorBoard events here (SB3 picks the columns).

        Resumed at ``resumed_at`` timesteps, ``progress.csv`` keeps the earlier run's rows up to it.
        """
        from stable_baselines3.common.logger import CSVOutputFormat, Logger, TensorBoardOutputFormat

        self.create()
        progress = self.path / "progress.csv"
        csv_log = CSVOutputFormat(str(progress)) if resumed_at is None else _resumed_sb3_csv(progress, resumed_at)
        return Logger(folder=str(self.path), output_formats=[csv_log, TensorBoardOutputFormat(str(self.path))])

    @contextmanager
    def interruptible(self, unit: str, save: Callable[[], Path]) -> Iterator[list[bool]]:
        """Run a training loop: Ctrl-C sets the yielded flag, the loop stops after the ``unit`` under way.

        Then ``save()`` writes a checkpoint and ``KeyboardInterrupt`` is raised; a second Ctrl-C raises it at once,
        without a checkpoint.
        """
        with deferred_interrupt(unit) as pressed:
            yield pressed
            if pressed:
                path = save()
                print(f"fxc train: interrupted; saved {path} (resume with --resume)", file=sys.stderr)
                raise KeyboardInterrupt

    def finish(self, timesteps: int, wrote: Path) -> Path | None:
        """Write ``training_curve.png`` and say what the run wrote; returns the curve's path (None without rows)."""
        curve = write_training_curve(self.path)
        print(f"fxc train: {timesteps} timesteps; wrote {wrote}" + (f" and {curve}" if curve else ""))
        return curve


class Progress:
    """``progress.csv`` with fixed ``columns``, and with ``tensorboard`` the same scalars as TensorBoard events.

    A run resumed from a checkpoint at ``resumed_at = (iterations, timesteps)`` drops the rows and events
    logged after it, so the log reads as one run. A row's TensorBoard step is its ``time/total_timesteps``.
    """

    def __init__(
        self, run_dir: Path, columns: Sequence[str], *, tensorboard: bool, resumed_at: tuple[int, int] | None
    ) -> None:
        self.path = run_dir / "progress.csv"
        self.columns = tuple(columns)
        kept: list[dict[str, str]] = []
        if resumed_at is not None and self.path.exists():
            with self.path.open(newline="") as handle:
                kept = [row for row in csv.DictReader(handle) if _iteration(row) <= resumed_at[0]]
        with self.path.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=self.columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(kept)
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            purge = resumed_at[1] + 1 if resumed_at is not None else None
            self.writer = SummaryWriter(str(run_dir), purge_step=purge)

    def write(self, row: Mapping[str, Any]) -> None:
        """Append ``row`` (a value per column; None: an empty cell and no TensorBoard scalar)."""
        with self.path.open("a", newline="") as handle:
            csv.writer(handle).writerow("" if row[c] is None else row[c] for c in self.columns)
        if self.writer is not None:
            for column in self.columns:
                if row[column] is not None:
                    self.writer.add_scalar(column, row[column], row["time/total_timesteps"])

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _resumed_sb3_csv(path: Path, timesteps: int) -> Any:
    """SB3's ``CSVOutputFormat`` on ``path``, holding the rows logged up to ``timesteps`` under their header.

    SB3 opens the file afresh; the kept rows are written back and the header becomes the
    writer's keys, so that SB3 extends both the way it does for a column it has not seen.
    """
    from stable_baselines3.common.logger import CSVOutputFormat

    lines = path.read_text().splitlines(keepends=True) if path.exists() else []
    writer = CSVOutputFormat(str(path))
    if lines:
        header = next(csv.reader([lines[0]]))
        if "time/total_timesteps" in header:
            column = header.index("time/total_timesteps")
            kept = [line for line in lines[1:] if _number(next(csv.reader([line]), []), column) <= timesteps]
            writer.keys = header
            writer.file.write(lines[0] + "".join(kept))
            writer.file.flush()
    return writer


def recorded_args(path: Path) -> dict[str, Any]:
    """The ``args`` a run's ``config.json`` at ``path`` records (``{}`` when it is missing or damaged)."""
    try:
        args = json.loads(path.read_text()).get("args", {}) if path.is_file() else {}
    except (OSError, UnicodeDecodeError, ValueError, AttributeError, RecursionError):
        return {}
    return args if isinstance(args, dict) else {}


def _number(cells: Sequence[str], column: int) -> float:
    text = cells[column] if column < len(cells) else ""
    return int(text) if text.isdigit() else float("inf")  # a damaged row goes


def _iteration(row: Mapping[str, str]) -> float:
    text = row.get("time/iterations") or ""
    return int(text) if text.isdigit() else float("inf")  # a damaged row goes


@contextmanager
def deferred_interrupt(unit: str) -> Iterator[list[bool]]:
    """Ctrl-C sets a flag (checked between ``unit``s) instead of breaking one; twice stops at once."""
    pressed: list[bool] = []
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        if pressed:
            raise KeyboardInterrupt
        pressed.append(True)
        print(f"\nfxc train: Ctrl-C; finishing this {unit}, then saving a checkpoint", file=sys.stderr)

    try:
        signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread: leave Ctrl-C alone
        yield pressed
        return
    try:
        yield pressed
    finally:
        signal.signal(signal.SIGINT, previous)


def write_training_curve(run_dir: Path) -> Path | None:
    """Plot ``rollout/ep_rew_mean`` against ``time/total_timesteps`` from ``progress.csv`` into ``training_curve.png``."""
    from fxc_env.analysis.plots import new_figure, save_figure

    progress = run_dir / "progress.csv"
    if not progress.exists():
        return None
    steps, returns = [], []
    with progress.open() as handle:
        for row in csv.DictReader(handle):
            if row.get("rollout/ep_rew_mean") and row.get("time/total_timesteps"):
                steps.append(float(row["time/total_timesteps"]))
                returns.append(float(row["rollout/ep_rew_mean"]))
    if not steps:
        return None
    fig = new_figure(6.5, 3.8)
    ax = fig.subplots()
    ax.plot(steps, returns, lw=0.8, color="#9ecae1", label="per rollout")
    window = 10
    if len(returns) >= window:
        smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
        ax.plot(steps[window - 1 :], smooth, lw=1.6, color="#08519c", label=f"mean of {window} rollouts")
        ax.legend(fontsize=8, loc="lower right")
    ax.set_xlabel("timesteps (agent-steps)")
    ax.set_ylabel("mean episode return = ln D(0)/D(T_s)")
    ax.set_title(f"training curve: {run_dir.name}", fontsize=9)
    ax.grid(alpha=0.3)
    return save_figure(fig, run_dir / "training_curve.png")
