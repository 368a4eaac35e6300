"""``fxc train`` (``--backend sb3``, the default): PPO or SAC (stable-baselines3) on :class:`fxc_env.ConsensusVecEnv`.

One policy is shared by every agent (parameter sharing): each agent of each parallel
episode is one SB3 sub-environment. Read top to bottom: the environment and the model, the
checkpoints, then :func:`train_sb3` (arguments, set-up, the loop, the final files). The run
directory is :mod:`fxc_env.training.run_dir`'s (config.json, versions.json, progress.csv and
TensorBoard events from SB3's logger, training_curve.png), plus:

    runs/<name>/checkpoints/model_<steps>_steps.zip  policy, optimiser and step count (SB3's ``save``),
                                                     VecNormalize statistics beside it when used
    runs/<name>/model.zip                            the final policy (+ vecnormalize.pkl)

``--backend rllib`` trains PPO in Ray RLlib instead (:mod:`fxc_env.training.rllib_train`),
``--backend torch`` a lean PPO loop on the batched engine (:mod:`fxc_env.training.torch_ppo`);
:func:`fxc_env.training.backends.train` picks one.
"""

from __future__ import annotations

import dataclasses
import pickle
import zipfile
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from fxc_env.core.validation import ArgumentError
from fxc_env.policies.policy_files import save_model
from fxc_env.training.args import TrainArgs, check_train_args
from fxc_env.training.imitation import imitate_reference
from fxc_env.training.run_dir import RunDir

#: ``policy_kwargs.activation_fn`` as written in the hyperparameter file.
ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu")


# ------------------------------------------------------------------------ environment and model
def build_env(args: TrainArgs, params: dict[str, Any]):
    """The monitored (and optionally normalised) ConsensusVecEnv of this run."""
    from stable_baselines3.common.vec_env import VecMonitor

    from fxc_env import ConsensusVecEnv

    env_kwargs = dict(params["env"])
    n_envs = args.n_envs or env_kwargs.pop("n_envs", 16)
    env_kwargs.pop("n_envs", None)
    venv = VecMonitor(ConsensusVecEnv(n_envs, scenario=args.scenario, **env_kwargs))
    venv.seed(args.seed)
    if params["normalize"]:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    return venv


def with_activation_class(policy_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``policy_kwargs`` with ``activation_fn`` given by name (``relu``) turned into torch's class."""
    import torch

    name = policy_kwargs.get("activation_fn")
    if name is None or not isinstance(name, str):
        return dict(policy_kwargs)
    classes = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU, "elu": torch.nn.ELU, "leaky_relu": torch.nn.LeakyReLU}
    if name not in classes:
        raise ArgumentError(f"hyperparams: activation_fn {name!r}; expected one of {ACTIVATIONS}")
    return {**policy_kwargs, "activation_fn": classes[name]}


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
        env.save(str(vecnormalize_path(path)))
    return path


def load_checkpoint(algo_class: Any, checkpoint: Path, venv: Any) -> tuple[Any, Any]:
    """The model saved at ``checkpoint`` on ``venv`` (with its VecNormalize statistics when ``venv`` normalizes).

    A damaged or truncated file (not a zip, a zip without SB3's entries, statistics that do not
    unpickle) is refused as ``resume``, naming the path.
    """
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


class RolloutCheckpoint(BaseCallback):
    """Save a checkpoint every ``every`` timesteps, at the start of a rollout; after Ctrl-C, save there and stop.

    The start of a rollout is just after the previous rollout's update. SB3's
    CheckpointCallback saves inside a rollout, before its update, so resuming from it would
    replay the rollout's steps without their gradient update. Once :attr:`pressed` (the flag
    of :meth:`RunDir.interruptible <fxc_env.training.run_dir.RunDir.interruptible>`) is set, the
    next rollout start saves (:attr:`saved_on_interrupt`) and the step after it stops SB3.
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
    import torch
    from stable_baselines3 import PPO, SAC

    args = dataclasses.replace(args, backend="sb3")
    params = check_train_args(args)  # every argument, before any work
    torch.set_num_threads(args.torch_threads)
    run = RunDir.of(args)
    checkpoint = run.resume_checkpoint(args.resume, args)

    # ------------------------------------------------------------------ set-up
    venv = build_env(args, params)
    algo_class = {"ppo": PPO, "sac": SAC}[args.algo]
    if checkpoint is not None:
        model, venv = load_checkpoint(algo_class, checkpoint, venv)
        run.announce_resume(checkpoint, f"{model.num_timesteps} timesteps")
    else:
        kwargs = dict(params["algo"])
        policy = policy_class(kwargs.pop("policy", "MlpPolicy"))
        kwargs["policy_kwargs"] = with_activation_class(kwargs.get("policy_kwargs", {}))
        model = algo_class(policy, venv, seed=args.seed, device="cpu", verbose=0, **kwargs)
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
