"""The arguments of ``fxc train``, shared by every back end, and the hyperparameter file.

:class:`TrainArgs` describes a run: each field declared once with its default and help text (:func:`arg`);
``fxc train``'s flags are built from the fields (:func:`add_train_parser`). Hyperparameters live in a YAML
file keyed by scenario, then algorithm (``hyperparams.yml`` beside this module). ``--task`` (a named task of
:mod:`fxc_env.config.tasks`) sets the environment from the task instead (:func:`task_hyperparams`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import typing
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fxc_env.config import make_config
from fxc_env.config.argument_types import StoreOnce
from fxc_env.config.tasks import NamedTask, get_task
from fxc_env.core.validation import ArgumentError, choice, integer
from fxc_env.training import registry
from fxc_env.utils.cli_checks import output_directory, yaml_mapping_file

HYPERPARAMS = Path(__file__).with_name("hyperparams.yml")
#: Views of :data:`fxc_env.training.registry.BACKENDS`: every ``--algo``, every ``--backend`` and the old names.
ALGORITHMS = registry.algorithms()
BACKENDS = tuple(registry.BACKENDS)
BACKEND_ALIASES = registry.ALIASES
#: ``--critic`` of the torch back end: per-agent values, or one value per episode from the global state.
CRITICS = ("local", "central")
#: ``--policy-arch`` of the torch back end (:mod:`fxc_env.policies.torch_memory`).
POLICY_ARCHS = ("mlp", "gru", "gnn")
#: Fields only ``--backend rllib`` reads: another back end refuses a value other than the default.
RLLIB_ONLY = ("num_env_runners", "envs_per_runner", "address")


def arg(default: Any, doc: str) -> Any:
    """A :class:`TrainArgs` field: its default and the help text ``fxc train --help`` shows for it."""
    return dataclasses.field(default=default, metadata={"help": doc})


@dataclass
class TrainArgs:
    """Arguments of one training run (``fxc train --help`` lists them, one flag per field)."""

    scenario: str = arg(
        "paper_fig1", "Named scenario of :data:`fxc_env.SCENARIOS`; also the key into the hyperparameter file."
    )
    task: str | None = arg(
        None,
        "A named task (``rings20-v2``, :data:`fxc_env.config.tasks.TASKS`): the environment is the task's as "
        "``fxc evaluate --task`` scores it (its settings and K, initial states drawn per episode), in place of "
        "``--scenario`` and the hyperparameter file's ``env`` (but ``n_envs``); hyperparameters from the file's "
        "entry for the task's id, else its scenario's, else ``default``. Not with ``--scenario``.",
    )
    algo: str = arg("ppo", "``ppo`` or ``sac``.")
    timesteps: int = arg(2_000_000, "Total agent-steps (SB3 timesteps: one per agent per environment step).")
    seed: int = arg(0, "Seeds the policy, SB3 and the episodes' initial states.")
    seeds: str | None = arg(
        None,
        "Several training seeds, one run each, in turn (``0-4``, ``0,2,5``); runs go to ``<run_dir>-seed<k>`` "
        "(or each seed's default). Not with ``--seed``. See :mod:`fxc_env.training.evaluation.seeds`.",
    )
    run_dir: str | None = arg(
        None, "Run directory; default ``runs/<scenario>-[<backend>-]<algo>-seed<seed>`` (no back-end part for sb3)."
    )
    checkpoint_every: int = arg(
        100_000, "Save a checkpoint every this many timesteps (rounded to whole environment steps)."
    )
    resume: bool = arg(
        False, "Continue from the newest checkpoint in ``run_dir`` (same step count, optimiser state, statistics)."
    )
    trust_policy_file: bool = arg(
        False,
        "With ``--resume``: also read run-directory files that only unpickling reads (RLlib checkpoints, SB3's "
        "loaders and VecNormalize .pkl, torch checkpoints beyond plain tensors); unpickling runs code from the "
        "file, so only for run directories you made or trust. Your own sb3 and torch runs resume without it.",
    )
    hyperparams: str = arg(str(HYPERPARAMS), "YAML file of hyperparameters keyed by scenario then algorithm.")
    n_envs: int | None = arg(None, "Parallel episodes; overrides the hyperparameter file.")
    progress_bar: bool = arg(True, "Show SB3's progress bar (torch: one line per rollout).")
    torch_threads: int = arg(1, "Threads torch may use.")
    backend: str = arg(
        "sb3",
        "``sb3`` (stable-baselines3 on this machine), ``rllib`` (Ray RLlib PPO on a local Ray or a cluster) or "
        "``torch`` (a lean PPO loop on the batched engine on a torch device; ``torchrl``, its old name, is deprecated) "
        "or ``diff`` (analytic policy gradients through the engine's closed-form intervals, "
        ":mod:`fxc_env.training.backends.diff_train`; ``--algo apg``, its default).",
    )
    num_env_runners: int = arg(2, "RLlib: env runner actors that sample in parallel (0: sample in this process).")
    envs_per_runner: int = arg(1, "RLlib: environments each env runner steps (``n_envs`` is the SB3 setting).")
    address: str | None = arg(
        None, "RLlib: the Ray cluster to join (``auto`` or ``HOST:6379``); default: start a local Ray."
    )
    device: str = arg(
        "cpu", "torch: the torch device of the episodes and the networks (``cpu``, ``cuda``, ``cuda:1``)."
    )
    critic: str = arg(
        "local",
        "torch: ``local`` (each agent's value from its own observation) or ``central`` (one value per episode "
        "from the normalized global state, shared by its agents).",
    )
    policy_arch: str = arg(
        "mlp",
        "torch: the actor, ``mlp`` (memoryless), ``gru`` (a GRU over the agent's own observations, reset per "
        "episode) or ``gnn`` (messages along the interval graph's edges: a communication model beyond the paper's).",
    )
    init_from: str | None = arg(
        None,
        "torch, diff: start a fresh run from a policy's weights: a shipped name (as ``load_learned_policy`` "
        "resolves it), a ``policy.pt`` or checkpoint, or a run directory. Its architecture and observation layout "
        "must be the run's (refused by name otherwise).",
    )


def flag_type(field: dataclasses.Field) -> type:
    """``bool``, ``int`` or ``str``: what the flag of a :class:`TrainArgs` field reads (``int | None`` is ``int``)."""
    hint = typing.get_type_hints(TrainArgs)[field.name]
    kinds = typing.get_args(hint) or (hint,)
    for kind in (bool, int):
        if kind in kinds:
            return kind
    return str


def canonical_backend(name: Any, *, warn: bool = True) -> Any:
    """``name``, or the back end an old name stands for (``torchrl`` -> ``torch``, with a ``DeprecationWarning``)."""
    if isinstance(name, str) and name in BACKEND_ALIASES:
        if warn:
            new = BACKEND_ALIASES[name]
            warnings.warn(f"backend {name!r} is deprecated; use {new!r}", DeprecationWarning, stacklevel=3)
        return BACKEND_ALIASES[name]
    return name


def load_hyperparams(path: str | Path, scenario: str, algo: str, *, name: str = "hyperparams") -> dict[str, Any]:
    """The ``env``, ``normalize`` and algorithm entries for ``scenario`` (or ``default``).

    ``algo`` is the entry's key (an older file's ``torchrl_ppo`` is read when it has no ``torch_ppo``). A
    missing or malformed file, or one without the entries, raises ArgumentError naming ``name``.
    """
    table = yaml_mapping_file(name, path)
    entry = table.get(scenario, table.get("default"))
    if entry is None:
        raise ArgumentError(f"{name}: {path} has neither {scenario!r} nor 'default'")
    if not isinstance(entry, dict):
        raise ArgumentError(f"{name}: the entry for {scenario!r} in {path} is not a mapping")
    key = "torchrl_ppo" if algo == "torch_ppo" and algo not in entry and "torchrl_ppo" in entry else algo
    if key not in entry:
        raise ArgumentError(f"algo: {path} has no {algo!r} entry for {scenario!r}")
    for part, value in (("env", entry.get("env", {})), (key, entry[key]), ("imitation", entry.get("imitation", {}))):
        if not isinstance(value, dict):
            raise ArgumentError(f"{name}: {part!r} of {scenario!r} in {path} is not a mapping")
    return {
        "env": dict(entry.get("env", {})),
        "normalize": bool(entry.get("normalize", False)),
        "algo": dict(entry[key]),
        # A warm start by imitating the reference (fxc_env.training.backends.imitation), PPO only; None: none.
        "imitation": dict(entry["imitation"]) if algo == "ppo" and "imitation" in entry else None,
    }


def check_train_args(args: TrainArgs, *, flags: bool = False) -> dict[str, Any]:
    """Check every argument of a run before work starts; returns the run's hyperparameters.

    Raises :class:`~fxc_env.core.validation.ArgumentError` naming the field (``n_envs``), or with ``flags`` the
    flag (``--n-envs``). ``--resume`` is checked by the back end
    (:meth:`~fxc_env.training.run_dir.RunDir.resume_checkpoint`), which knows its checkpoint layout.
    """

    def name(field: str) -> str:
        return "--" + field.replace("_", "-") if flags else field

    if args.seeds is not None:
        raise ArgumentError(
            f"{name('seeds')}: one run trains one seed; fxc train --seeds (fxc_env.training.evaluation.seeds.train_seeds) "
            "trains several"
        )
    choice(name("backend"), canonical_backend(args.backend), BACKENDS)
    args = dataclasses.replace(args, backend=canonical_backend(args.backend, warn=False))
    _check_backend_fields(args, name)
    choice(name("algo"), args.algo, ALGORITHMS)
    integer(name("timesteps"), args.timesteps, 1)
    integer(name("seed"), args.seed, 0, 2**32 - 1)  # numpy's legacy seeding, which SB3 uses, takes 32 bits
    integer(name("checkpoint_every"), args.checkpoint_every, 1)
    integer(name("torch_threads"), args.torch_threads, 1)
    if args.n_envs is not None:
        integer(name("n_envs"), args.n_envs, 1)
    integer(name("num_env_runners"), args.num_env_runners, 0)
    integer(name("envs_per_runner"), args.envs_per_runner, 1)
    if args.trust_policy_file and not args.resume:
        raise ArgumentError(
            f"{name('trust_policy_file')}: only --resume reads files from a run directory; a fresh run would ignore it "
            "(add --resume, or leave it out)"
        )
    for field in RLLIB_ONLY if args.backend != "rllib" else ():
        value, default = getattr(args, field), TrainArgs.__dataclass_fields__[field].default
        if value != default:
            raise ArgumentError(
                f"{name(field)}: only the rllib backend reads it; the {args.backend} backend would ignore "
                f"{value!r} (use --backend rllib, or leave it out)"
            )
    params = _checked_hyperparams(args, name)
    output_directory(name("run_dir"), args.run_dir or default_run_dir(args))
    return params


def _only(flag: str) -> str:
    """``the torch and diff backends``: the back ends with ``flag`` set, for error messages."""
    names = registry.with_flag(flag)
    return f"the {' and '.join(names)} backend{'s' if len(names) > 1 else ''}"


def _check_backend_fields(args: TrainArgs, name: Any) -> None:
    """The algorithm, actor, critic, device and ``--init-from`` that ``args.backend`` can honour."""
    backend = registry.BACKENDS[args.backend]
    if args.algo in ALGORITHMS and args.algo not in backend.algorithms:
        owners = [b for b in registry.BACKENDS.values() if args.algo in b.algorithms]
        if len(backend.algorithms) > 1 and len(owners) == 1:  # a back end with a choice: say where it is
            raise ArgumentError(
                f"{name('algo')}: {args.algo!r} needs {owners[0].requires}: use --backend {owners[0].name}"
            )
        expected = " or ".join(repr(a) for a in backend.algorithms)
        raise ArgumentError(
            f"{name('algo')}: the {args.backend} backend trains {expected}{backend.algorithm_note}, got {args.algo!r}"
        )
    choice(name("critic"), args.critic, CRITICS)
    choice(name("policy_arch"), args.policy_arch, POLICY_ARCHS)
    if not backend.torch_actor and args.policy_arch != "mlp":
        raise ArgumentError(
            f"{name('policy_arch')}: only {_only('torch_actor')} have a choice of actor, got {args.policy_arch!r}"
        )
    if not backend.critics and args.critic != "local":
        raise ArgumentError(f"{name('critic')}: only {_only('critics')} has a choice of critic, got {args.critic!r}")
    if not backend.torch_actor and args.device != "cpu":
        raise ArgumentError(
            f"{name('device')}: only {_only('torch_actor')} run on a chosen device, got {args.device!r}"
        )
    if backend.torch_actor:
        torch_device(name("device"), args.device)
    if args.init_from is not None and not backend.torch_actor:
        raise ArgumentError(
            f"{name('init_from')}: only {_only('torch_actor')} start from a policy file, not the {args.backend} backend"
        )
    if args.init_from is not None and args.resume:
        raise ArgumentError(
            f"{name('init_from')}: --resume goes on from the run's own checkpoint; "
            "--init-from starts a fresh run (leave one out)"
        )


def _checked_hyperparams(args: TrainArgs, name: Any) -> dict[str, Any]:
    """The run's entry of the hyperparameter file, its environment and the back end's settings checked."""
    backend = registry.BACKENDS[args.backend]
    algo_key = backend.hyperparams_key.format(backend=args.backend, algo=args.algo)
    task = None if args.task is None else _task(args, name)
    if task is None:
        params = load_hyperparams(args.hyperparams, args.scenario, algo_key, name=name("hyperparams"))
    else:
        params = task_hyperparams(args.hyperparams, task, algo_key, name=name("hyperparams"))
    if args.backend == "rllib":
        batch = params["algo"].get("train_batch_size_per_learner")
        integer(f"{name('hyperparams')}: {algo_key}.train_batch_size_per_learner", batch, 1)
    try:
        config = make_config(**env_settings(args, params))
    except ArgumentError as exc:
        source = f"{name('scenario')} {args.scenario!r}" if task is None else f"{name('task')} {task.id!r}"
        raise type(exc)(f"{source} with the env of {args.hyperparams}: {exc}") from exc
    if backend.settings is not None:
        from fxc_env.training import settings

        getattr(settings, backend.settings).from_mapping(params["algo"], config, name=name("hyperparams"))
    return params


def _task(args: TrainArgs, name: Any) -> NamedTask:
    """The run's named task; a ``--scenario`` beside it is refused (the task fixes the environment)."""
    task = get_task(args.task, name("task"))
    if args.scenario != TrainArgs.__dataclass_fields__["scenario"].default:
        raise ArgumentError(
            f"{name('scenario')}: --task {task.id} sets the environment (its settings and K); "
            f"leave out --scenario {args.scenario!r}"
        )
    return task


def env_settings(args: TrainArgs, params: dict[str, Any]) -> dict[str, Any]:
    """The run's environment keywords: ``--scenario`` and the hyperparameter file's ``env`` (or the task's, whose
    ``scenario`` replaces it: :func:`task_hyperparams`), without ``n_envs``."""
    return {"scenario": args.scenario, **{k: v for k, v in params["env"].items() if k != "n_envs"}}


def env_label(args: TrainArgs) -> str:
    """What a run trains on, for its console lines: the task's id, or the scenario."""
    return args.scenario if args.task is None else get_task(args.task, "task").id


def task_hyperparams(path: str | Path, task: NamedTask, algo: str, *, name: str = "hyperparams") -> dict[str, Any]:
    """A task's run: the file's entry for the task's id, else its scenario's, else ``default``; the env the task's.

    The environment is the task's as ``fxc evaluate --task`` scores it: its settings (its scenario as the
    ``scenario`` keyword, K included) with ``initial_state="random"`` (each episode draws its own), plus the
    entry's ``n_envs``. An entry keyed by the task's id whose ``env`` holds more than ``n_envs`` is refused
    naming ``name`` (the task fixes the rest); another entry's ``env`` is its scenario's and is not read.
    """
    table = yaml_mapping_file(name, path)
    settings = task.kwargs()
    key = task.id if task.id in table else settings.get("scenario") or "default"
    params = load_hyperparams(path, key, algo, name=name)
    extra = sorted(set(params["env"]) - {"n_envs"})
    if key == task.id and extra:
        raise ArgumentError(
            f"{name}: the env of {task.id!r} in {path} sets {', '.join(extra)}; the task fixes its environment "
            "(only n_envs may be given)"
        )
    counts = {"n_envs": params["env"]["n_envs"]} if "n_envs" in params["env"] else {}
    env = {"scenario": settings.pop("scenario", None), **settings, "initial_state": "random"}
    return {**params, "env": {**counts, **env}}


def default_run_dir(args: TrainArgs) -> str:
    """``runs/<scenario>-[<backend>-]<algo>-seed<seed>`` (no back-end part for sb3; ``--task``: its id for the scenario).

    A torch run resumed without ``--run-dir`` goes on in ``runs/<scenario>-torchrl-...``, the
    default of the back end's old name, when only that one exists.
    """
    backend = canonical_backend(args.backend, warn=False)
    part = "" if backend == "sb3" else f"{backend}-"
    path = f"runs/{env_label(args)}-{part}{args.algo}-seed{args.seed}"
    if backend == "torch" and args.resume and not Path(path).exists():
        legacy = f"runs/{args.scenario}-torchrl-{args.algo}-seed{args.seed}"
        if Path(legacy).is_dir():
            return legacy
    return path


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


# ---------------------------------------------------------------------------- command line
def add_train_parser(commands: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``fxc train``: one flag per :class:`TrainArgs` field, with its default and help text.

    A bool field is ``--flag/--no-flag``; every other flag is read as text, for :func:`check_train_args` to
    refuse a bad value naming the flag.
    """
    parser = commands.add_parser(
        "train",
        help="train a shared policy with PPO or SAC (stable-baselines3), PPO in Ray RLlib (--backend rllib), "
        "a lean torch PPO on the batched engine (--backend torch, --device cpu|cuda), or analytic policy gradients "
        "through the engine (--backend diff)",
    )
    for field in dataclasses.fields(TrainArgs):
        flag = "--" + field.name.replace("_", "-")
        help_text = field.metadata["help"]
        if flag_type(field) is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=field.default, help=help_text)
        else:
            parser.add_argument(flag, default=field.default, help=help_text, action=RecordedFlag)
    return parser


class RecordedFlag(StoreOnce):
    """Store a flag's text and record its field in ``namespace.given_flags`` (``--seed`` with ``--seeds`` is
    refused); a flag given twice is refused (:class:`~fxc_env.config.argument_types.StoreOnce`)."""


def args_from_namespace(namespace: argparse.Namespace) -> TrainArgs:
    """The :class:`TrainArgs` an ``fxc train`` command line asks for.

    Integer flags are converted (text that is not an integer is kept, for
    :func:`check_train_args` to refuse naming the flag). ``--backend torchrl`` is read as
    ``--backend torch``, with a one-line deprecation message on stderr.
    """
    values = {}
    for field in dataclasses.fields(TrainArgs):
        value = getattr(namespace, field.name)
        if flag_type(field) is int and isinstance(value, str):
            try:
                value = int(value)
            except ValueError:
                pass
        values[field.name] = value
    if values["backend"] in BACKEND_ALIASES:
        new = BACKEND_ALIASES[values["backend"]]
        print(f"fxc train: --backend {values['backend']} is deprecated; use --backend {new}", file=sys.stderr)
        values["backend"] = new
    given = getattr(namespace, "given_flags", set())
    backend = registry.BACKENDS.get(values["backend"])
    if backend and values["algo"] not in backend.algorithms and "algo" not in given:
        values["algo"] = backend.algorithms[0]  # --backend diff alone trains its one algorithm
    return TrainArgs(**values)
