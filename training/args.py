"""The arguments of ``fxc train``, shared by every back end, and the hyperparameter file.

:class:`TrainArgs` is the one description of a training run: ``fxc train --help`` is built
from its fields and their docstrings (:func:`add_train_parser`), and each back end
(:mod:`fxc_env.training.sb3_train` for stable-baselines3, :mod:`fxc_env.training.rllib_train`
for Ray RLlib, :mod:`fxc_env.training.torch_ppo` for the lean torch PPO loop) reads it.
Hyperparameters live in a YAML file keyed by scenario, then algorithm (``hyperparams.yml``
beside this module).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import itertools
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fxc_env.core.validation import ArgumentError, choice, integer
from fxc_env.utils.cli_checks import yaml_mapping_file

HYPERPARAMS = Path(__file__).with_name("hyperparams.yml")
ALGORITHMS = ("ppo", "sac")
BACKENDS = ("sb3", "rllib", "torchrl")
#: ``--critic`` of the torchrl back end: per-agent values, or one value per episode from the global state.
CRITICS = ("local", "central")


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
    """Show SB3's progress bar (torchrl: one line per rollout)."""
    torch_threads: int = 1
    """Threads torch may use."""
    backend: str = "sb3"
    """``sb3`` (stable-baselines3 on this machine), ``rllib`` (Ray RLlib PPO on a local Ray or a cluster) or ``torchrl`` (a lean PPO loop on the batched engine on a torch device)."""
    num_env_runners: int = 2
    """RLlib: env runner actors that sample in parallel (0: sample in this process)."""
    envs_per_runner: int = 1
    """RLlib: environments each env runner steps (``n_envs`` is the SB3 setting)."""
    address: str | None = None
    """RLlib: the Ray cluster to join (``auto`` or ``HOST:6379``); default: start a local Ray."""
    device: str = "cpu"
    """torchrl: the torch device of the episodes and the networks (``cpu``, ``cuda``, ``cuda:1``)."""
    critic: str = "local"
    """torchrl: ``local`` (each agent's value from its own observation) or ``central`` (one value per episode from the normalized global state, shared by its agents)."""


def load_hyperparams(path: str | Path, scenario: str, algo: str, *, name: str = "hyperparams") -> dict[str, Any]:
    """The ``env``, ``normalize`` and algorithm entries for ``scenario`` (or ``default``).

    A missing or malformed file, or one without the entries, raises
    :class:`~fxc_env.core.validation.ArgumentError` naming ``name`` (``--hyperparams`` on the command line).
    """
    table = yaml_mapping_file(name, path)
    entry = table.get(scenario, table.get("default"))
    if entry is None:
        raise ArgumentError(f"{name}: {path} has neither {scenario!r} nor 'default'")
    if not isinstance(entry, dict):
        raise ArgumentError(f"{name}: the entry for {scenario!r} in {path} is not a mapping")
    if algo not in entry:
        raise ArgumentError(f"algo: {path} has no {algo!r} entry for {scenario!r}")
    for key, value in (("env", entry.get("env", {})), (algo, entry[algo]), ("imitation", entry.get("imitation", {}))):
        if not isinstance(value, dict):
            raise ArgumentError(f"{name}: {key!r} of {scenario!r} in {path} is not a mapping")
    return {
        "env": dict(entry.get("env", {})),
        "normalize": bool(entry.get("normalize", False)),
        "algo": dict(entry[algo]),
        # A warm start by imitating the reference (fxc_env.training.imitation), PPO only; None: none.
        "imitation": dict(entry["imitation"]) if algo == "ppo" and "imitation" in entry else None,
    }


def check_train_args(args: TrainArgs, *, flags: bool = False) -> dict[str, Any]:
    """Check every argument of a run before work starts; returns the run's hyperparameters.

    Raises :class:`~fxc_env.core.validation.ArgumentError` naming the argument: the field
    name (``n_envs``), or with ``flags`` the command-line flag (``--n-envs``). Checked: the
    back end and algorithm, the counts and thresholds, the seed, the hyperparameter file
    (a YAML mapping with an entry for the scenario and algorithm), the environment it
    describes, and that the run directory can be created. ``--resume`` without a
    checkpoint is refused by the back end, which knows its checkpoint layout.
    """
    from fxc_env.config import make_config
    from fxc_env.utils.cli_checks import output_directory

    def name(field: str) -> str:
        return "--" + field.replace("_", "-") if flags else field

    choice(name("backend"), args.backend, BACKENDS)
    if args.backend in ("rllib", "torchrl") and args.algo != "ppo":
        raise ArgumentError(f"{name('algo')}: the {args.backend} backend trains 'ppo', got {args.algo!r}")
    choice(name("critic"), args.critic, CRITICS)
    if args.backend != "torchrl" and args.critic != "local":
        raise ArgumentError(f"{name('critic')}: only the torchrl backend has a choice of critic, got {args.critic!r}")
    if args.backend != "torchrl" and args.device != "cpu":
        raise ArgumentError(f"{name('device')}: only the torchrl backend runs on a chosen device, got {args.device!r}")
    if args.backend == "torchrl":
        torch_device(name("device"), args.device)
    choice(name("algo"), args.algo, ALGORITHMS)
    integer(name("timesteps"), args.timesteps, 1)
    integer(name("seed"), args.seed, 0, 2**32 - 1)  # numpy's legacy seeding, which SB3 uses, takes 32 bits
    integer(name("checkpoint_every"), args.checkpoint_every, 1)
    integer(name("torch_threads"), args.torch_threads, 1)
    if args.n_envs is not None:
        integer(name("n_envs"), args.n_envs, 1)
    integer(name("num_env_runners"), args.num_env_runners, 0)
    integer(name("envs_per_runner"), args.envs_per_runner, 1)
    algo_key = f"{args.backend}_{args.algo}" if args.backend in ("rllib", "torchrl") else args.algo
    params = load_hyperparams(args.hyperparams, args.scenario, algo_key, name=name("hyperparams"))
    if args.backend == "rllib":
        batch = params["algo"].get("train_batch_size_per_learner")
        integer(f"{name('hyperparams')}: {algo_key}.train_batch_size_per_learner", batch, 1)
    try:
        config = make_config(args.scenario, **{k: v for k, v in params["env"].items() if k != "n_envs"})
    except ArgumentError as exc:
        raise type(exc)(f"{name('scenario')} {args.scenario!r} with the env of {args.hyperparams}: {exc}") from exc
    if args.backend == "torchrl":
        from fxc_env.training.torch_ppo import PPOSettings

        PPOSettings.from_mapping(params["algo"], config, name=name("hyperparams"))
    output_directory(name("run_dir"), args.run_dir or default_run_dir(args))
    return params


def default_run_dir(args: TrainArgs) -> str:
    """``runs/<scenario>-[<backend>-]<algo>-seed<seed>`` (no back-end part for sb3)."""
    backend = "" if args.backend == "sb3" else f"{args.backend}-"
    return f"runs/{args.scenario}-{backend}{args.algo}-seed{args.seed}"


def torch_device(name: str, value: Any) -> Any:
    """``value`` as a ``torch.device`` this machine has; raise naming ``name`` otherwise."""
    import torch

    try:
        device = torch.device(value)
    except (RuntimeError, TypeError) as exc:
        raise ArgumentError(f"{name}: expected a torch device such as 'cpu' or 'cuda', got {value!r}") from exc
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ArgumentError(
                f"{name}: {value!r} asks for CUDA, but torch.cuda.is_available() is False on this machine"
            )
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ArgumentError(f"{name}: {value!r}, but this machine has {torch.cuda.device_count()} CUDA device(s)")
    elif device.type != "cpu":
        raise ArgumentError(f"{name}: expected 'cpu' or a CUDA device, got {value!r}")
    return device


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


def add_train_parser(commands: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``fxc train``: one option per :class:`TrainArgs` field."""
    parser = commands.add_parser(
        "train",
        help="train a shared policy with PPO or SAC (stable-baselines3), PPO in Ray RLlib (--backend rllib), "
        "or a lean torch PPO on the batched engine (--backend torchrl, --device cpu|cuda)",
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
    return parser


def args_from_namespace(namespace: argparse.Namespace) -> TrainArgs:
    """The :class:`TrainArgs` an ``fxc train`` command line asks for."""
    names = {field.name for field in dataclasses.fields(TrainArgs)}
    return TrainArgs(**{k: v for k, v in vars(namespace).items() if k in names})
