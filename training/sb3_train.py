"""``fxc train``: PPO or SAC (stable-baselines3) on :class:`fxc_env.ConsensusVecEnv`.

This is the stable-baselines3 back end; ``--backend rllib`` trains PPO in Ray RLlib instead
(:mod:`fxc_env.training.rllib_train`), and :func:`fxc_env.training.backends.train` picks one.

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

import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from fxc_env.core.validation import ArgumentError
from fxc_env.training.args import TrainArgs, check_train_args
from fxc_env.training.artefacts import versions, write_training_curve
from fxc_env.training.imitation import imitate_reference


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


#: ``policy_kwargs.activation_fn`` as written in the hyperparameter file.
ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu")


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


def train_sb3(args: TrainArgs) -> Path:
    """Run (or resume) training with stable-baselines3; returns the run directory."""
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    from fxc_env.training.checkpoints import RolloutCheckpoint, latest_checkpoint, save_checkpoint, vecnormalize_path

    params = check_train_args(dataclasses.replace(args, backend="sb3"))  # every argument, before any work
    torch.set_num_threads(args.torch_threads)
    run_dir = Path(args.run_dir or f"runs/{args.scenario}-{args.algo}-seed{args.seed}")

    # ------------------------------------------------------------------ set-up
    venv = build_env(args, params)
    algo_class = {"ppo": PPO, "sac": SAC}[args.algo]
    checkpoint = latest_checkpoint(run_dir) if args.resume else None
    if args.resume and checkpoint is None:
        raise ArgumentError(f"resume: no checkpoint in {run_dir / 'checkpoints'}")
    if checkpoint is not None:
        if isinstance(venv, VecNormalize):
            venv = VecNormalize.load(str(vecnormalize_path(checkpoint)), venv.venv)
        model = algo_class.load(checkpoint, env=venv, device="cpu")
        print(f"fxc train: resuming {run_dir} from {checkpoint.name} at {model.num_timesteps} timesteps")
    else:
        run_dir.mkdir(parents=True, exist_ok=True)
        kwargs = dict(params["algo"])
        policy = kwargs.pop("policy", "MlpPolicy")
        kwargs["policy_kwargs"] = with_activation_class(kwargs.get("policy_kwargs", {}))
        policy = policy_class(policy)
        model = algo_class(policy, venv, seed=args.seed, device="cpu", verbose=0, **kwargs)
        record = {"args": dataclasses.asdict(args), "hyperparams": params, "num_envs": venv.num_envs}
        if params["imitation"] is not None:
            fit = imitate_reference(model, venv, params["imitation"], args.seed)
            record["imitation"] = fit
            print(
                f"fxc train: imitated {params['imitation'].get('teacher', 'reference')} on {fit['samples']:.0f} agent-steps "
                f"(relative action error {fit['relative_action_rms_error']:.2e}); PPO goes on from there"
            )
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
