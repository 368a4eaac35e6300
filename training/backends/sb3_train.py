"""``fxc train`` (``--backend sb3``, the default): PPO or SAC (stable-baselines3) on :class:`fxc_env.ConsensusVecEnv`.

One policy shared by every agent: each agent of each parallel episode is one SB3 sub-environment. The run
directory is :mod:`fxc_env.training.run_dir`'s, plus:

    runs/<name>/checkpoints/model_<steps>_steps.zip  policy, optimiser and step count (SB3's ``save``),
                                                     VecNormalize statistics beside it (``.pkl`` and ``.json``)
    runs/<name>/model.zip                            the final policy (+ vecnormalize.pkl)
"""

from __future__ import annotations

import dataclasses
import json
import math
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from fxc_env.core.validation import ArgumentError
from fxc_env.policies.policy_files import TRUST_HINT, read_sb3_zip, save_model
from fxc_env.training.args import TrainArgs, env_settings
from fxc_env.training.backends.checkpoint_checks import check_resumed_state
from fxc_env.training.backends.imitation import imitate_reference
from fxc_env.training.run_dir import TRAIN_TRUST_HINT, RunDir, begin_run

#: The format of the plain-JSON VecNormalize record beside each checkpoint, and its float settings.
VECNORMALIZE_FORMAT = "fxc_env.vecnormalize/1"
VECNORMALIZE_FLOATS = ("clip_obs", "clip_reward", "gamma", "epsilon")


# ------------------------------------------------------------------------ environment and model
def build_env(args: TrainArgs, params: dict[str, Any]):
    """The monitored (and optionally normalised) ConsensusVecEnv of this run."""
    from stable_baselines3.common.vec_env import VecMonitor

    from fxc_env import ConsensusVecEnv

    n_envs = args.n_envs or params["env"].get("n_envs", 16)
    venv = VecMonitor(ConsensusVecEnv(n_envs, **env_settings(args, params)))
    venv.seed(args.seed)
    if params["normalize"]:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    return venv


def with_activation_class(policy_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``policy_kwargs`` with ``activation_fn`` given by name (``relu``) turned into torch's class."""
    from fxc_env.policies.networks import SB3_ACTIVATIONS

    name = policy_kwargs.get("activation_fn")
    if name is None or not isinstance(name, str):
        return dict(policy_kwargs)
    if name not in SB3_ACTIVATIONS:
        raise ArgumentError(f"hyperparams: activation_fn {name!r}; expected one of {tuple(SB3_ACTIVATIONS)}")
    return {**policy_kwargs, "activation_fn": SB3_ACTIVATIONS[name]}


def policy_class(name: str) -> Any:
    """SB3's policy names (``MlpPolicy``) as given; a dotted path (``fxc_env.policies.gain_network.GainScheduledPolicy``) imported."""
    if "." not in name:
        return name
    import importlib

    module, _, attribute = name.rpartition(".")
    try:
        return getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError) as exc:
        raise ArgumentError(f"hyperparams: policy {name!r} cannot be imported ({exc})") from exc


# ---------------------------------------------------------------------------------- checkpoints
def vecnormalize_path(checkpoint: Path) -> Path:
    """Where the VecNormalize statistics of ``checkpoint`` are kept (SB3's naming)."""
    return checkpoint.with_name(checkpoint.name.replace("model_", "model_vecnormalize_", 1)).with_suffix(".pkl")


def save_checkpoint(model: Any, run: RunDir) -> Path:
    """Save ``model`` (optimiser included) and any VecNormalize statistics as ``model_<steps>_steps``."""
    path = run.checkpoint_path(model.num_timesteps)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, path)  # SB3's save plus fxc_policy.json: loads without unpickling
    env = model.get_env()
    if isinstance(env, VecNormalize):
        env.save(str(vecnormalize_path(path)))  # SB3's pickle, for SB3's own tools and --trust-policy-file
        vecnormalize_record_path(path).write_text(json.dumps(vecnormalize_record(env)) + "\n")  # what resume reads
    return path


def vecnormalize_record_path(checkpoint: Path) -> Path:
    """Where the plain-JSON copy of the VecNormalize statistics of ``checkpoint`` is kept (``.json`` beside SB3's ``.pkl``)."""
    return vecnormalize_path(checkpoint).with_suffix(".json")


def vecnormalize_record(venv: VecNormalize) -> dict[str, Any]:
    """VecNormalize's running statistics and settings as plain JSON (what :func:`restore_vecnormalize` reads)."""

    def stats(rms: Any) -> dict[str, Any]:
        return {"mean": np.asarray(rms.mean).tolist(), "var": np.asarray(rms.var).tolist(), "count": float(rms.count)}

    return {
        "format": VECNORMALIZE_FORMAT,
        "obs_rms": stats(venv.obs_rms),
        "ret_rms": stats(venv.ret_rms),
        **{key: float(getattr(venv, key)) for key in VECNORMALIZE_FLOATS},
        "norm_obs": bool(venv.norm_obs),
        "norm_reward": bool(venv.norm_reward),
    }


def restore_vecnormalize(venv: VecNormalize, path: Path) -> None:
    """Set ``venv``'s running statistics from the plain-JSON record at ``path`` (nothing is unpickled).

    A record that is damaged, of another format, of another observation shape or of other
    normalisation settings than ``venv`` is refused as ``resume``, naming the path.
    """
    try:
        record = json.loads(path.read_text())
        if not isinstance(record, dict) or record.get("format") != VECNORMALIZE_FORMAT:
            raise ValueError(f"not a {VECNORMALIZE_FORMAT!r} record")
        for flag in ("norm_obs", "norm_reward"):
            if record[flag] is not getattr(venv, flag):
                raise ValueError(f"{flag} {record[flag]!r}, this run's VecNormalize has {getattr(venv, flag)!r}")
        for name, shape in (("obs_rms", venv.observation_space.shape), ("ret_rms", ())):
            mean, var = (np.asarray(record[name][key], dtype=np.float64) for key in ("mean", "var"))
            count = float(record[name]["count"])
            if mean.shape != shape or var.shape != shape:
                raise ValueError(f"{name} of shape {mean.shape}, this run's observations have {shape}")
            if not (np.all(np.isfinite(mean)) and np.all(var >= 0) and math.isfinite(count) and count > 0):
                raise ValueError(f"{name} holds a non-finite mean, a negative variance or a count <= 0")
            rms = getattr(venv, name)
            rms.mean, rms.var, rms.count = mean, var, count
        for key in VECNORMALIZE_FLOATS:
            setattr(venv, key, float(record[key]))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, RecursionError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ArgumentError(f"resume: cannot read the VecNormalize statistics {str(path)!r} ({first})") from exc


def load_checkpoint(
    algo_class: Any, checkpoint: Path, venv: Any, *, trusted: bool = False, model: Any = None
) -> tuple[Any, Any]:
    """The model saved at ``checkpoint`` on ``venv`` (with its VecNormalize statistics when ``venv`` normalizes).

    Without ``trusted`` nothing is unpickled (:func:`restore_checkpoint`, :func:`restore_vecnormalize`); with it,
    SB3's own ``load`` and ``VecNormalize.load``. A damaged or truncated file is refused as ``resume``, naming
    the path.
    """
    if not trusted:
        if isinstance(venv, VecNormalize):
            record = vecnormalize_record_path(checkpoint)
            if not record.is_file():
                pickled = vecnormalize_path(checkpoint)
                raise ArgumentError(
                    f"resume: the VecNormalize statistics of {checkpoint.name} are "
                    + (
                        f"only in {str(pickled)!r}, a pickle (reading it runs code from the file); "
                        if pickled.is_file()
                        else f"missing ({record.name}); "
                    )
                    + TRAIN_TRUST_HINT
                )
            restore_vecnormalize(venv, record)
        return restore_checkpoint(model, checkpoint), venv
    path = checkpoint
    try:
        if isinstance(venv, VecNormalize):
            path = vecnormalize_path(checkpoint)
            venv = VecNormalize.load(str(path), venv.venv)
            path = checkpoint
        return algo_class.load(checkpoint, env=venv, device="cpu"), venv
    except (OSError, EOFError, KeyError, ValueError, RuntimeError, zipfile.BadZipFile, pickle.UnpicklingError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ArgumentError(f"resume: cannot read the checkpoint {str(path)!r} ({first})") from exc


def restore_checkpoint(model: Any, checkpoint: Path) -> Any:
    """``model`` (this run's, freshly built) with the weights, optimiser state and step count of ``checkpoint``.

    Nothing is unpickled (:func:`~fxc_env.policies.policy_files.read_sb3_zip`, refused otherwise naming
    ``--trust-policy-file``; state dicts with ``weights_only=True``). It must be of this run's algorithm and network.
    """
    from stable_baselines3.common.save_util import load_from_zip_file, recursive_getattr

    try:
        saved = read_sb3_zip(checkpoint)
    except (ArgumentError, FileNotFoundError) as exc:
        reason = str(exc).removeprefix("policy: ").replace(TRUST_HINT, TRAIN_TRUST_HINT)
        raise ArgumentError(f"resume: cannot read the checkpoint {str(checkpoint)!r} ({reason})") from exc
    algorithm = type(model).__name__
    if saved.algorithm != algorithm:
        raise ArgumentError(
            f"algo: the checkpoint {str(checkpoint)!r} is a {saved.algorithm} model, this run trains {algorithm}"
        )
    try:
        _, params, variables = load_from_zip_file(checkpoint, load_data=False, device="cpu")
        with zipfile.ZipFile(checkpoint) as archive:
            data = json.loads(archive.read("data"))
        names, variable_names = model._get_torch_save_params()
        if set(params) != set(names):
            raise ValueError(f"it holds the state of {sorted(params)}, a {algorithm} run saves {sorted(names)}")
        model.set_parameters(params, exact_match=True, device="cpu")
        for name in variable_names:
            value = (variables or {}).get(name)
            if not isinstance(value, torch.Tensor):
                raise ValueError(f"it lacks the tensor {name!r}")
            recursive_getattr(model, name).data.copy_(value.data)
        model.num_timesteps = saved.num_timesteps
        updates = data.get("_n_updates", 0)
        model._n_updates = updates if isinstance(updates, int) and not isinstance(updates, bool) else 0
    except (pickle.UnpicklingError, RuntimeError, ValueError, KeyError, TypeError, OSError) as exc:
        first = " ".join((str(exc).strip().splitlines() or [type(exc).__name__])[:1])
        hint = f"; {TRAIN_TRUST_HINT}" if isinstance(exc, pickle.UnpicklingError) else ""
        raise ArgumentError(
            f"resume: the checkpoint {str(checkpoint)!r} does not fit this run's {algorithm} network and "
            f"hyperparameters ({first}){hint}"
        ) from exc
    return model


def check_resumed_model(model: Any, run: RunDir, checkpoint: Path, target: int) -> None:
    """Refuse to go on from ``checkpoint`` (as ``resume``, naming it and the field) unless the SB3 ``model`` loaded
    from it has finite weights and optimiser state and a step count in ``[0, target]`` equal to its name's
    (:func:`~fxc_env.training.backends.checkpoint_checks.check_resumed_state`)."""
    from stable_baselines3.common.save_util import recursive_getattr

    state_dicts, variables = model._get_torch_save_params()
    check_resumed_state(
        run,
        checkpoint,
        target,
        steps=("num_timesteps", model.num_timesteps),
        counters={"_n_updates": model._n_updates},
        weights={**model.policy.state_dict(), **{name: recursive_getattr(model, name) for name in variables}},
        optimizers={name: recursive_getattr(model, name).state_dict() for name in state_dicts if name != "policy"},
    )


class RolloutCheckpoint(BaseCallback):
    """Save a checkpoint every ``every`` timesteps, at the start of a rollout; after Ctrl-C, save there and stop.

    (SB3's CheckpointCallback saves before a rollout's update, which a resume would skip.) Once :attr:`pressed`
    is set, the next rollout start saves (:attr:`saved_on_interrupt`) and the step after it stops SB3.
    """

    def __init__(self, run: RunDir, every: int) -> None:
        super().__init__()
        self.run, self.every = run, every
        self.pressed: list[bool] = []
        self.last = 0
        self.saved_on_interrupt: Path | None = None

    def _on_training_start(self) -> None:
        self.last = self.model.num_timesteps

    def _on_rollout_start(self) -> None:
        if self.pressed:
            self.saved_on_interrupt = save_checkpoint(self.model, self.run)
        elif self.model.num_timesteps - self.last >= self.every:
            save_checkpoint(self.model, self.run)
            self.last = self.model.num_timesteps

    def _on_step(self) -> bool:
        return self.saved_on_interrupt is None  # False stops SB3's learn()


# ------------------------------------------------------------------------------------- training
def train_sb3(args: TrainArgs) -> Path:
    """Run (or resume) training with stable-baselines3; returns the run directory."""
    from stable_baselines3 import PPO, SAC

    args, params, run, checkpoint = begin_run(args, "sb3")

    # ------------------------------------------------------------------ set-up
    venv = build_env(args, params)
    algo_class = {"ppo": PPO, "sac": SAC}[args.algo]
    kwargs = dict(params["algo"])  # this run's hyperparameter file (never the run directory's config.json)
    policy = policy_class(kwargs.pop("policy", "MlpPolicy"))
    kwargs["policy_kwargs"] = with_activation_class(kwargs.get("policy_kwargs", {}))
    model = algo_class(policy, venv, seed=args.seed, device="cpu", verbose=0, **kwargs)
    if checkpoint is not None:
        model, venv = load_checkpoint(algo_class, checkpoint, venv, trusted=args.trust_policy_file, model=model)
        check_resumed_model(model, run, checkpoint, args.timesteps)
        run.announce_resume(checkpoint, f"{model.num_timesteps} timesteps")
    else:
        record = {"args": dataclasses.asdict(args), "hyperparams": params, "num_envs": venv.num_envs}
        if params["imitation"] is not None:
            fit = imitate_reference(model, venv, params["imitation"], args.seed)
            record["imitation"] = fit
            print(
                f"fxc train: imitated {params['imitation'].get('teacher', 'reference')} on {fit['samples']:.0f} agent-steps "
                f"(relative action error {fit['relative_action_rms_error']:.2e}); PPO goes on from there"
            )
        run.start(record)
    model.set_logger(run.sb3_logger(resumed_at=None if checkpoint is None else model.num_timesteps))

    # ------------------------------------------------------------------- loop
    callback = RolloutCheckpoint(run, args.checkpoint_every)
    with run.interruptible("rollout", lambda: callback.saved_on_interrupt or save_checkpoint(model, run)) as pressed:
        callback.pressed = pressed  # after Ctrl-C: a checkpoint at the next rollout start, then stop
        remaining = args.timesteps - model.num_timesteps
        if remaining > 0:
            model.learn(
                remaining, callback=callback, reset_num_timesteps=checkpoint is None, progress_bar=args.progress_bar
            )

    # -------------------------------------------------------------- artefacts
    save_checkpoint(model, run)  # a later --resume with more --timesteps goes on from here
    save_model(model, run.path / "model.zip")
    if isinstance(venv, VecNormalize):
        venv.save(str(run.path / "vecnormalize.pkl"))
    run.finish(model.num_timesteps, run.path / "model.zip")
    venv.close()
    return run.path
