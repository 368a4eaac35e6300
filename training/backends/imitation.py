"""A warm start for PPO: the policy first imitates an analytic law (the paper's controller by default), then PPO improves on it.

A network that copies the reference (eq. 11) to within a few per cent already contracts the disagreement
almost as fast (an action error eps turns the per-interval contraction rho into about rho + eps).
:func:`imitate_reference` rolls the reference out on the run's own VecEnv (Gaussian noise on the executed
actions, clean labels), regresses the policy's mean on the labels and its value function on the discounted
returns, and sets the log standard deviation. Configured by the ``imitation`` entry of the hyperparameter
file; runs once when a run starts (never on ``--resume``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fxc_env.baselines.registry import LAWS
from fxc_env.config import config_of
from fxc_env.core.validation import ArgumentError

#: Defaults of the ``imitation`` entry of the hyperparameter file.
DEFAULTS = {
    "teacher": "reference",  # the paper's controller, or "saturation_aware" (fxc_env.baselines)
    "samples": 2_000_000,  # agent-steps of reference demonstrations, rounded up to whole episodes
    "noise": 0.05,  # standard deviation of the executed actions' noise (normalized units)
    "epochs": 10,
    "batch_size": 4096,
    "learning_rate": 1.0e-3,  # Adam's step size at the first epoch ...
    "final_learning_rate": 3.0e-5,  # ... decayed geometrically to this at the last
    "log_std": -3.0,  # the policy's log standard deviation after imitation (PPO explores around the copy)
}


def teacher_policy(name: str, config: Any) -> Any:
    """The policy to copy, in the run's own units (plan actions, normalized observations)."""
    teachers = ("reference", "saturation_aware")  # registered laws (fxc_env.baselines.registry) that plan
    if name not in teachers:
        raise ArgumentError(f"hyperparams: imitation teacher {name!r}; expected one of {teachers}")
    return LAWS[name].policy(config)


@dataclass(frozen=True)
class Demonstrations:
    """The teacher's demonstrations on a VecEnv of ``n_envs`` sub-environments (one per agent and episode).

    float32 ``observations [steps, n_envs, obs_size]``, ``actions [steps, n_envs, action_size]`` (the teacher's
    clean action, the label) and ``returns [steps, n_envs]`` (discounted, the value target); ``steps`` whole episodes.
    """

    observations: np.ndarray
    actions: np.ndarray
    returns: np.ndarray


def demonstrations(
    venv: Any, teacher: Any, samples: int, noise: float, gamma: float, rng: np.random.Generator
) -> Demonstrations:
    """Roll ``teacher`` out on ``venv`` for at least ``samples`` agent-steps, rounded up to whole episodes.

    The executed actions have Gaussian noise ``noise`` (normalized units, from ``rng``); the labels are clean.
    """
    config = config_of(venv, "imitation")
    n_envs, episode = venv.num_envs, config.n_intervals
    steps = math.ceil(int(samples) / (n_envs * episode)) * episode  # whole episodes
    observations = np.empty((steps, n_envs, config.layout.size), dtype=np.float32)
    actions = np.empty((steps, n_envs, config.action_size), dtype=np.float32)
    rewards = np.empty((steps, n_envs))
    dones = np.empty((steps, n_envs), dtype=bool)
    obs = venv.reset()
    for t in range(steps):
        target = teacher(obs)
        observations[t], actions[t] = obs, target
        obs, rewards[t], dones[t], _ = venv.step(target + noise * rng.standard_normal(target.shape))
    returns = np.empty((steps, n_envs), dtype=np.float32)
    following = np.zeros(n_envs)
    for t in reversed(range(steps)):
        following = rewards[t] + gamma * following * ~dones[t]
        returns[t] = following
    return Demonstrations(observations, actions, returns)


def imitate_reference(model: Any, venv: Any, settings: dict[str, Any], seed: int) -> dict[str, float]:
    """Behaviour-clone the teacher into ``model`` (an SB3 PPO) on ``venv``; returns the fit's figures.

    ``settings`` overrides :data:`DEFAULTS`; an unknown key or teacher raises ArgumentError naming
    ``hyperparams`` before anything is touched. Returns ``samples``, ``relative_action_rms_error`` (on up to
    100,000 demonstrations) and ``value_rms_error``. Deterministic for a given ``seed`` on the CPU.
    """
    import torch

    options = {**DEFAULTS, **settings}
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        raise ArgumentError(f"hyperparams: unknown imitation key(s) {sorted(unknown)}; expected {sorted(DEFAULTS)}")
    config = config_of(venv, "imitation")
    reference = teacher_policy(str(options["teacher"]), config)
    rng = np.random.default_rng(seed)
    data = demonstrations(venv, reference, int(options["samples"]), options["noise"], float(model.gamma), rng)

    policy = model.policy
    x = torch.as_tensor(data.observations.reshape(-1, config.layout.size))
    y = torch.as_tensor(data.actions.reshape(-1, config.action_size))
    g = torch.as_tensor(data.returns.reshape(-1, 1))
    optimizer = torch.optim.Adam(policy.parameters(), lr=float(options["learning_rate"]))
    generator = torch.Generator().manual_seed(seed)
    batch = int(options["batch_size"])
    epochs = int(options["epochs"])
    decay = (float(options["final_learning_rate"]) / float(options["learning_rate"])) ** (1.0 / max(epochs - 1, 1))
    for epoch in range(epochs):
        for group in optimizer.param_groups:
            group["lr"] = float(options["learning_rate"]) * decay**epoch
        order = torch.randperm(len(x), generator=generator)
        for start in range(0, len(x), batch):
            index = order[start : start + batch]
            mean = policy.get_distribution(x[index]).distribution.mean
            loss = torch.nn.functional.mse_loss(mean, y[index]) + torch.nn.functional.mse_loss(
                policy.predict_values(x[index]), g[index]
            )
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    with torch.no_grad():
        policy.log_std.fill_(float(options["log_std"]))
        sample = torch.arange(0, len(x), max(1, len(x) // 100_000))
        mean = policy.get_distribution(x[sample]).distribution.mean
        action_error = float(torch.sqrt(torch.mean((mean - y[sample]) ** 2)) / torch.sqrt(torch.mean(y[sample] ** 2)))
        value_error = float(torch.sqrt(torch.mean((policy.predict_values(x[sample]) - g[sample]) ** 2)))
    return {"samples": float(len(x)), "relative_action_rms_error": action_error, "value_rms_error": value_error}
