"""What the torch back ends (:mod:`fxc_env.training.backends.torch_ppo`, :mod:`fxc_env.training.backends.diff_train`) share:
the Gaussian actor-critic, Adam, the policy record and checkpoints (:class:`TrainerFiles`), ``--init-from``
(:func:`init_actor`) and the run loop (:func:`drive`).

The policy record is the file :func:`fxc_env.policies.torch_policy.load_torch_policy` reads (its module
gives the keys); a checkpoint holds it under ``"policy"`` beside the networks, Adam's state, the step
counts and every generator's state.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from fxc_env.config import make_config
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import training_domain
from fxc_env.policies.fit import training_settings
from fxc_env.policies.learned import SHIPPED, pretrained_path
from fxc_env.policies.networks import mlp
from fxc_env.policies.records import file_tensor
from fxc_env.policies.torch_memory import build_actor
from fxc_env.policies.torch_policy import CHECKPOINT_FORMAT, POLICY_FORMAT, is_torch_policy, load_torch_policy, one_line
from fxc_env.training.args import TrainArgs, env_settings
from fxc_env.training.backends.checkpoint_checks import check_resumed_state, check_written_by
from fxc_env.training.run_dir import TRAIN_TRUST_HINT, RunDir, begin_run
from fxc_env.training.settings import PPOSettings


class TrainerFiles:
    def policy_record(self) -> dict[str, Any]:
        """The policy file's dictionary (see the module docstring)."""
        return {
            "format": POLICY_FORMAT,
            "obs_size": self.obs_size,
            "action_size": self.action_size,
            "action_bound": self.bound,
            "hidden": list(self.settings.hidden),
            "activation": self.settings.activation,
            "arch": self.arch,
            **self.arch_entries(),
            "actor": {k: v.detach().cpu().clone() for k, v in self.model.actor.state_dict().items()},
            "log_std": self.model.log_std.detach().cpu().clone(),
            "env": dict(self.env_kwargs),
            "domain": training_domain(self.config),
            "timesteps": self.timesteps,
        }

    def arch_entries(self) -> dict[str, Any]:
        """The policy record's entries of the ``gru`` (``gru_size``, ``clock_index``, ``gru_input``,
        ``rows_end``) or ``gnn`` (``embed_size``, ``rounds``) actor."""
        if self.arch == "gru":
            return {
                "gru_size": self.settings.gru_size,
                "clock_index": self.clock_index,
                "gru_input": self.settings.gru_input,
                "rows_end": self.rows_end,
            }
        if self.arch == "gnn":
            return {"embed_size": self.settings.embed_size, "rounds": self.settings.message_rounds}
        return {}

    def save_checkpoint(self, run: RunDir) -> Path:
        """Networks, Adam's state, counters and every generator's state as ``checkpoints/model_<timesteps>_steps.pt``."""
        path = run.checkpoint_path(self.timesteps)
        path.parent.mkdir(parents=True, exist_ok=True)
        engine_rng = self.engine.rng.get_state() if isinstance(self.engine.rng, torch.Generator) else None
        record = {
            "format": CHECKPOINT_FORMAT,
            "backend": self.args.backend,  # torch and diff share the name and format: resume checks which
            "timesteps": self.timesteps,
            "iterations": self.iterations,
            "n_updates": self.n_updates,
            "model": {k: v.detach().cpu() for k, v in self.model.state_dict().items()},
            "optimizer": self.optimizer.state_dict(),
            "rng": {
                "torch": torch.get_rng_state(),
                "generator": self.generator.get_state(),
                "engine": engine_rng,
                "host": self.host_rng.bit_generator.state,
            },
            "policy": self.policy_record(),
        }
        partial = path.with_suffix(".pt.partial")
        torch.save(record, partial)
        partial.replace(path)  # a checkpoint is either whole or absent
        return path

    def load_checkpoint(self, path: Path, run: RunDir, *, trusted: bool = False) -> None:
        """Go on from the checkpoint at ``path`` of ``run``: read with ``weights_only=True`` (tensors and plain values,
        no code), or, with ``trusted`` (``--trust-policy-file``), unpickled (:mod:`fxc_env.training.run_dir`); what
        it holds is checked (:mod:`fxc_env.training.backends.checkpoint_checks`) before the run goes on."""
        try:
            record = torch.load(path, map_location="cpu", weights_only=not trusted)
        except pickle.UnpicklingError as exc:  # weights_only met a pickled object (a crafted file) or garbage
            raise ArgumentError(
                f"resume: cannot read the checkpoint {str(path)!r} as tensors and plain values ({one_line(exc, 160)}); "
                f"{TRAIN_TRUST_HINT}"
            ) from exc
        except (OSError, EOFError, RuntimeError, ValueError) as exc:  # garbage or cut short
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise ArgumentError(f"resume: cannot read the checkpoint {str(path)!r} ({first})") from exc
        if not isinstance(record, dict) or record.get("format") != CHECKPOINT_FORMAT:
            raise ArgumentError(f"resume: {str(path)!r} is not a torch back-end checkpoint")

        rng = record.get("rng")
        missing = [
            key for key in ("model", "optimizer", "timesteps", "iterations", "n_updates", "rng") if key not in record
        ]
        missing += [
            f"rng.{key}" for key in ("torch", "generator", "engine", "host") if isinstance(rng, dict) and key not in rng
        ]
        if missing:
            raise ArgumentError(
                f"resume: the checkpoint {str(path)!r} lacks {', '.join(missing)} (damaged, or another version's)"
            )
        check_written_by(run, path, record.get("backend"))  # before its network meets this back end's
        try:
            self.model.load_state_dict(record["model"])
        except (RuntimeError, TypeError, AttributeError) as exc:  # missing, extra or misshapen weights
            raise ArgumentError(
                f"resume: {str(path)!r} was trained with other network settings: {one_line(exc)}"
            ) from exc
        self._restore_state(path, record)
        check_resumed_state(
            run,
            path,
            self.args.timesteps,
            steps=("timesteps", self.timesteps),
            counters={"iterations": self.iterations, "n_updates": self.n_updates},
            weights=self.model.state_dict(),
            optimizers={"optimizer": self.optimizer.state_dict()},
        )
        for group in self.optimizer.param_groups:  # this run's --hyperparams set the step size, as sb3's do
            group["lr"] = self.settings.learning_rate
        self._reset()  # a resumed run starts fresh episodes

    def _restore_state(self, path: Path, record: Mapping[str, Any]) -> None:
        """Adam's state, the counters and the generators of the checkpoint ``record`` read from ``path``."""
        rng = record["rng"]
        try:
            self.optimizer.load_state_dict(record["optimizer"])
            for group in self.optimizer.param_groups:  # Adam's moments must fit the weights they follow
                for weight in group["params"]:
                    for name, value in self.optimizer.state.get(weight, {}).items():
                        if isinstance(value, torch.Tensor) and value.ndim and value.shape != weight.shape:
                            raise ValueError(
                                f"optimizer state {name!r} of shape {tuple(value.shape)} for a weight {tuple(weight.shape)}"
                            )
            self.timesteps = int(record["timesteps"])
            self.iterations = int(record["iterations"])
            self.n_updates = int(record["n_updates"])
            torch.set_rng_state(rng["torch"])
            self.generator.set_state(rng["generator"])
            if rng["engine"] is not None and isinstance(self.engine.rng, torch.Generator):
                self.engine.rng.set_state(rng["engine"])
            self.host_rng.bit_generator.state = rng["host"]
        except (KeyError, RuntimeError, TypeError, ValueError, AttributeError, OverflowError) as exc:
            raise ArgumentError(
                f"resume: the checkpoint {str(path)!r} holds a damaged optimizer, counter or generator state: {one_line(exc)}"
            ) from exc


LOG_2PI = math.log(2.0 * math.pi)


class ActorCritic(nn.Module):
    """The shared Gaussian policy (mean network, state-independent log std) and the critic.

    ``arch``: the mean network (``mlp``, ``gru`` or ``gnn``, :mod:`fxc_env.policies.torch_memory`);
    ``clock_index``: the observation entry of ``k/K`` (``gru`` resets where it is 0). The critic is an MLP.
    """

    def __init__(
        self,
        obs_size: int,
        action_size: int,
        critic_size: int,
        settings: PPOSettings,
        arch: str = "mlp",
        clock_index: int = -1,
        rows_end: int = 0,
    ) -> None:
        super().__init__()
        record = {"arch": arch, "hidden": settings.hidden, "activation": settings.activation, "rows_end": rows_end}
        record.update(gru_size=settings.gru_size, clock_index=clock_index, gru_input=settings.gru_input)
        record.update(embed_size=settings.embed_size, rounds=settings.message_rounds)
        self.actor = build_actor(record, obs_size, action_size, settings.actor_out_gain)
        self.log_std = nn.Parameter(torch.full((action_size,), settings.log_std_init))
        self.critic = mlp(critic_size, 1, settings.hidden, settings.activation, 1.0)

    def log_prob(self, mean: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        z = (actions - mean) * torch.exp(-self.log_std)
        return -0.5 * (z * z).sum(-1) - self.log_std.sum() - 0.5 * LOG_2PI * mean.shape[-1]

    def entropy(self) -> torch.Tensor:
        return (self.log_std + 0.5 * (1.0 + LOG_2PI)).sum()


def adam(parameters: Iterator[nn.Parameter], learning_rate: float) -> torch.optim.Adam:
    """SB3's Adam (``eps = 1e-5``), fused (one kernel for every parameter) where torch has it for the device."""
    parameters = list(parameters)
    try:
        return torch.optim.Adam(parameters, lr=learning_rate, eps=1e-5, fused=True)
    except (RuntimeError, TypeError):
        return torch.optim.Adam(parameters, lr=learning_rate, eps=1e-5)


def latest_torch_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint with the most timesteps in ``run_dir/checkpoints`` (None if there is none)."""
    return RunDir(run_dir, "torch").newest_checkpoint()


#: The settings of a policy's environment that fix what its observation and action entries mean.
LAYOUT_SETTINGS = ("obs_mode", "obs_slots", "obs_size", "limit_feature", "dim", "action_mode", "action_size")


def init_actor(trainer: Any, source: str) -> Path:
    """Load the actor (and exploration noise) of ``source`` into ``trainer``'s model (``--init-from``).

    ``source``: a shipped policy's name, a ``policy.pt``, a checkpoint or a torch or diff run directory. Refused
    by name, the model unchanged: not a torch policy, another architecture or another observation layout
    (:data:`LAYOUT_SETTINGS`) than the run's.
    """
    path = pretrained_path(source) if source in SHIPPED and not Path(source).exists() else Path(source)
    if not is_torch_policy(path):
        raise ArgumentError(
            f"init_from: {source!r} is not a torch policy (expected a shipped torch policy such as 'rings_gru', a "
            "policy.pt or checkpoint of --backend torch or diff, or such a run directory)"
        )
    try:
        policy = load_torch_policy(path)
    except ArgumentError as exc:
        raise ArgumentError(f"init_from: {exc}") from exc
    file = path / "policy.pt" if path.is_dir() else path
    record = torch.load(file, map_location="cpu", weights_only=True)  # load_torch_policy read it already
    record = record.get("policy", record) if record.get("format") == CHECKPOINT_FORMAT else record
    run = trainer.policy_record()
    for key in ("arch", "obs_size", "action_size", "hidden", "activation", *trainer.arch_entries()):
        theirs, ours = record.get(key, "mlp" if key == "arch" else None), run[key]
        if theirs != ours:
            what = "observation layout" if key == "obs_size" else "architecture"
            raise ArgumentError(
                f"init_from: {source!r} has another {what} than this run: {key} {theirs!r} there, {ours!r} here"
            )
    trained, here = policy.training_settings, training_settings(trainer.config)
    for key in LAYOUT_SETTINGS if trained else ():
        if key in trained and trained[key] != here[key]:
            raise ArgumentError(
                f"init_from: {source!r} has another observation layout than this run: {key} {trained[key]!r} there, "
                f"{here[key]!r} here"
            )
    log_std = _initial_log_std(record, file, tuple(trainer.model.log_std.shape))
    trainer.model.actor.load_state_dict(policy.module.state_dict())
    with torch.no_grad():
        trainer.model.log_std.copy_(log_std.to(trainer.model.log_std))
    return path


def _initial_log_std(record: Mapping[str, Any], file: Path, shape: tuple[int, ...]) -> torch.Tensor:
    """The ``log_std`` of the policy record read from ``file``, once it is a finite tensor of ``shape``
    (:func:`fxc_env.policies.records.file_tensor`); else the error naming ``init_from``, the file and ``log_std``."""
    if "log_std" not in record:
        raise ArgumentError(f"init_from: {file} has no log_std (the exploration noise a run starts from)")
    try:
        return torch.as_tensor(file_tensor(file, "log_std", record["log_std"], shape))
    except ArgumentError as exc:
        raise ArgumentError(f"init_from: {exc}") from exc


def prepare(args: TrainArgs, backend: str, settings_class: Any, trainer_class: Any) -> tuple[Any, ...]:
    """Every argument checked before any work, then ``(args, params, run, checkpoint, trainer)`` of a torch back end."""
    args, params, run, checkpoint = begin_run(args, backend)
    settings = settings_class.from_mapping(params["algo"], make_config(**run_config(args, params)))
    return args, params, run, checkpoint, trainer_class(args, params, settings, torch.device(args.device))


def drive(
    args: TrainArgs,
    run: RunDir,
    trainer: Any,
    checkpoint: Path | None,
    params: Mapping[str, Any],
    record: Mapping[str, Any],
    banner: str,
    unit: str,
    iterate: Any,
    columns: tuple[str, ...],
) -> Path:
    """The run every back end on the torch engine shares (``torch``, ``diff``); returns the run directory.

    Resumes ``checkpoint`` (or starts the run directory), calls ``iterate(start_steps, start_time)`` (one
    ``unit``: advances ``trainer.timesteps``, returns its progress row and console line) until ``args.timesteps``
    with checkpoints every ``args.checkpoint_every`` and on Ctrl-C, and writes ``policy.pt``.
    """
    if checkpoint is not None:
        trainer.load_checkpoint(checkpoint, run, trusted=args.trust_policy_file)
        run.announce_resume(checkpoint, f"{trainer.timesteps} timesteps")
    else:
        meta = {"n_envs": trainer.n_envs, "n_agents": trainer.n_agents}
        run.start({"args": dataclasses.asdict(args), "hyperparams": params, **record, **meta})
    if args.progress_bar:
        print(banner)
    resumed_at = (trainer.iterations, trainer.timesteps) if checkpoint is not None else None
    start_steps, start_time = trainer.timesteps, time.perf_counter()
    last_checkpoint = trainer.timesteps
    with (
        run.progress(columns, tensorboard=True, resumed_at=resumed_at) as progress,
        run.interruptible(unit, lambda: trainer.save_checkpoint(run)) as interrupted,
    ):
        while trainer.timesteps < args.timesteps and not interrupted:
            row, line = iterate(start_steps, start_time)
            progress.write(row)
            if args.progress_bar:
                print(line)
            if trainer.timesteps - last_checkpoint >= args.checkpoint_every:
                trainer.save_checkpoint(run)
                last_checkpoint = trainer.timesteps
    trainer.save_checkpoint(run)  # a later --resume with more --timesteps goes on from here
    torch.save(trainer.policy_record(), run.path / "policy.pt")
    run.finish(trainer.timesteps, run.path / "policy.pt")
    return run.path


def run_config(args: TrainArgs, params: dict[str, Any]) -> dict[str, Any]:
    """The environment keywords of this run (:func:`~fxc_env.training.args.env_settings`; a central critic's state)."""
    kwargs = env_settings(args, params)
    if args.critic == "central":
        kwargs["global_state"] = "normalized"
    return kwargs
