"""``fxc train``: PPO or SAC (stable-baselines3) on :class:`fxc_env.ConsensusVecEnv`.

``--backend rllib`` trains PPO in Ray RLlib instead, locally or on a Ray cluster
(:mod:`training.rllib_train`); the rest of this page is the stable-baselines3 backend.

One policy is shared by every agent (parameter sharing): each agent of each parallel
episode is one SB3 sub-environment. Read top to bottom: arguments, set-up, the training
loop (with checkpoints and Ctrl-C handling), then the artefacts of the run directory:

    runs/<name>/config.json        the exact arguments and resolved hyperparameters
    runs/<name>/versions.json      Python and library versions
    runs/<name>/progress.csv       SB3 log (TensorBoard event files beside it)
    runs/<name>/checkpoints/       model_<steps>_steps.zip (+ VecNormalize statistics)
    runs/<name>/model.zip          the final policy
    runs/<name>/training_curve.png mean episode return against timesteps
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import itertools
import json
import platform
import sys
import textwrap
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import yaml

HYPERPARAMS = Path(__file__).with_name("hyperparams.yml")
ALGORITHMS = ("ppo", "sac")
BACKENDS = ("sb3", "rllib")


@dataclass
class TrainArgs:
    """Arguments of one training run (``fxc train --help`` lists them too)."""

    scenario: str = "paper_fig1"
    """Named scenario of :data:`fxc_env.SCENARIOS`; also the key into the hyperparameter file."""
    algo: str = "ppo"
    """``ppo`` or ``sac``."""
    timesteps: int = 2_000_000
    """Total agent-steps (SB3 timesteps: one per agent per environment step)."""
    seed: int = 0
    """Seeds the policy, SB3 and the episodes' initial states."""
    run_dir: str | None = None
    """Run directory; default ``runs/<scenario>-<algo>-seed<seed>``."""
    checkpoint_every: int = 100_000
    """Save a checkpoint every this many timesteps (rounded to whole environment steps)."""
    resume: bool = False
    """Continue from the newest checkpoint in ``run_dir`` (same step count, optimiser state, statistics)."""
    hyperparams: str = str(HYPERPARAMS)
    """YAML file of hyperparameters keyed by scenario then algorithm."""
    n_envs: int | None = None
    """Parallel episodes; overrides the hyperparameter file."""
    progress_bar: bool = True
    """Show SB3's progress bar."""
    torch_threads: int = 1
    """Threads torch may use."""
    backend: str = "sb3"
    """``sb3`` (stable-baselines3 on this machine) or ``rllib`` (Ray RLlib PPO on a local Ray or a cluster)."""
    num_env_runners: int = 2
    """RLlib: env runner actors that sample in parallel (0: sample in this process)."""
    envs_per_runner: int = 1
    """RLlib: environments each env runner steps (``n_envs`` is the SB3 setting)."""
    address: str | None = None
    """RLlib: the Ray cluster to join (``auto`` or ``HOST:6379``); default: start a local Ray."""


def load_hyperparams(path: str | Path, scenario: str, algo: str) -> dict[str, Any]:
    """The ``env``, ``normalize`` and algorithm entries for ``scenario`` (or ``default``)."""
    table = yaml.safe_load(Path(path).read_text())
    entry = table.get(scenario, table.get("default"))
    if entry is None:
        raise ValueError(f"hyperparams: {path} has neither {scenario!r} nor 'default'")
    if algo not in entry:
        raise ValueError(f"algo: {path} has no {algo!r} entry for {scenario!r}")
    return {
        "env": dict(entry.get("env", {})),
        "normalize": bool(entry.get("normalize", False)),
        "algo": dict(entry[algo]),
    }


def versions() -> dict[str, str]:
    """Python and the versions of the libraries a run depends on."""
    found = {"python": platform.python_version()}
    for name in ("fxc-env", "numpy", "gymnasium", "pettingzoo", "stable-baselines3", "torch", "ray"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def build_env(args: TrainArgs, params: dict[str, Any]):
    """The monitored (and optionally normalised) ConsensusVecEnv of this run."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from fxc_env import ConsensusVecEnv

    env_kwargs = dict(params["env"])
    n_envs = args.n_envs or env_kwargs.pop("n_envs", 16)
    env_kwargs.pop("n_envs", None)
    venv = VecMonitor(ConsensusVecEnv(n_envs, scenario=args.scenario, **env_kwargs))
    venv.seed(args.seed)
    if params["normalize"]:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    return venv


def train(args: TrainArgs) -> Path:
    """Run (or resume) training; returns the run directory."""
    if args.backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {args.backend!r}")
    if args.timesteps < 1:
        raise ValueError(f"timesteps: expected an integer >= 1, got {args.timesteps!r}")
    if args.backend == "rllib":
        from fxc_env.cluster import import_ray

        import_ray("--backend rllib")
        from training.rllib_train import train_rllib

        return train_rllib(args)
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    from training.checkpoints import RolloutCheckpoint, latest_checkpoint, save_checkpoint, vecnormalize_path

    if args.algo not in ALGORITHMS:
        raise ValueError(f"algo: expected one of {ALGORITHMS}, got {args.algo!r}")
    torch.set_num_threads(args.torch_threads)
    run_dir = Path(args.run_dir or f"runs/{args.scenario}-{args.algo}-seed{args.seed}")
    params = load_hyperparams(args.hyperparams, args.scenario, args.algo)

    # ------------------------------------------------------------------ set-up
    venv = build_env(args, params)
    algo_class = {"ppo": PPO, "sac": SAC}[args.algo]
    checkpoint = latest_checkpoint(run_dir) if args.resume else None
    if args.resume and checkpoint is None:
        raise ValueError(f"resume: no checkpoint in {run_dir / 'checkpoints'}")
    if checkpoint is not None:
        if isinstance(venv, VecNormalize):
            venv = VecNormalize.load(str(vecnormalize_path(checkpoint)), venv.venv)
        model = algo_class.load(checkpoint, env=venv, device="cpu")
        print(f"fxc train: resuming {run_dir} from {checkpoint.name} at {model.num_timesteps} timesteps")
    else:
        run_dir.mkdir(parents=True, exist_ok=True)
        kwargs = dict(params["algo"])
        policy = kwargs.pop("policy", "MlpPolicy")
        model = algo_class(policy, venv, seed=args.seed, device="cpu", verbose=0, **kwargs)
        record = {"args": dataclasses.asdict(args), "hyperparams": params, "num_envs": venv.num_envs}
        (run_dir / "config.json").write_text(json.dumps(record, indent=2) + "\n")
        (run_dir / "versions.json").write_text(json.dumps(versions(), indent=2) + "\n")
    model.set_logger(configure(str(run_dir), ["csv", "tensorboard"]))
    checkpoints = RolloutCheckpoint(run_dir / "checkpoints", args.checkpoint_every)

    # ------------------------------------------------------------------- loop
    remaining = args.timesteps - model.num_timesteps
    try:
        if remaining > 0:
            model.learn(
                remaining, callback=checkpoints, reset_num_timesteps=checkpoint is None, progress_bar=args.progress_bar
            )
    except KeyboardInterrupt:
        # Ctrl-C loses nothing: a checkpoint at the current step count, then stop.
        path = save_checkpoint(model, run_dir / "checkpoints")
        print(f"\nfxc train: interrupted; saved {path} (resume with --resume)", file=sys.stderr)
        raise

    # -------------------------------------------------------------- artefacts
    save_checkpoint(model, run_dir / "checkpoints")  # a later --resume with more --timesteps goes on from here
    model.save(run_dir / "model.zip")
    if isinstance(venv, VecNormalize):
        venv.save(str(run_dir / "vecnormalize.pkl"))
    curve = write_training_curve(run_dir)
    print(
        f"fxc train: {model.num_timesteps} timesteps; wrote {run_dir / 'model.zip'}"
        + (f" and {curve}" if curve else "")
    )
    venv.close()
    return run_dir


def write_training_curve(run_dir: Path) -> Path | None:
    """Plot ``rollout/ep_rew_mean`` against ``time/total_timesteps`` from ``progress.csv``."""
    import csv

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

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
    fig = Figure(figsize=(6.5, 3.8), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot(steps, returns, lw=1.2)
    ax.set_xlabel("timesteps (agent-steps)")
    ax.set_ylabel("mean episode return = ln D(0)/D(T_s)")
    ax.set_title(f"training curve: {run_dir.name}", fontsize=9)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path = run_dir / "training_curve.png"
    fig.savefig(path)
    return path


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (the text ``--help`` shows)."""
    body = ast.parse(textwrap.dedent(inspect.getsource(cls))).body[0].body  # type: ignore[attr-defined]
    docs = {}
    for node, following in itertools.pairwise(body):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(following, ast.Expr)
            and isinstance(following.value, ast.Constant)
        ):
            docs[node.target.id] = str(following.value.value)  # type: ignore[union-attr]
    return docs


def add_train_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``fxc train``: one option per :class:`TrainArgs` field."""
    parser = commands.add_parser(
        "train", help="train a shared policy with PPO or SAC (stable-baselines3), or PPO in Ray RLlib (--backend rllib)"
    )
    defaults = TrainArgs()
    docs = field_docs(TrainArgs)
    for field in dataclasses.fields(TrainArgs):
        flag = "--" + field.name.replace("_", "-")
        default = getattr(defaults, field.name)
        if isinstance(default, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=docs.get(field.name))
        else:
            kind = int if field.type in ("int", "int | None") else str
            parser.add_argument(flag, type=kind, default=default, help=docs.get(field.name))
    parser.set_defaults(handler=lambda ns: train_command(ns))


def train_command(namespace: argparse.Namespace) -> int:
    names = {field.name for field in dataclasses.fields(TrainArgs)}
    args = TrainArgs(**{k: v for k, v in vars(namespace).items() if k in names})
    try:
        train(args)
    except KeyboardInterrupt:
        return 130
    return 0
