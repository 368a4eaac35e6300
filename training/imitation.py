"""A warm start for PPO: the policy first imitates an analytic law (the paper's controller by default), then PPO improves on it.

The reference (eq. 11) is a known good policy, and a network that copies it to within a
few per cent already contracts the disagreement almost as fast: in normalized units an
action error of relative size eps turns the per-interval contraction rho into about
rho + eps, so over K = 200 intervals it costs about a decade, not the deadline. PPO from
scratch needs most of its budget to get there; behaviour cloning gets there in a minute, and
PPO then spends its budget where the reference is not optimal (energy, input limits).

:func:`imitate_reference` rolls the reference out on the run's own VecEnv (with Gaussian
noise on the executed actions, so states off the reference's path are covered, and labels
that are always the clean reference action), regresses the policy's mean on those labels
and its value function on the discounted returns, and sets the policy's log standard
deviation. It is configured by the ``imitation`` entry of the hyperparameter file and runs
once, when a run starts (never on ``--resume``); the run's ``config.json`` records it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

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
    from fxc_env.baselines.saturation_aware import SaturationAwarePolicy
    from fxc_env.core.validation import ArgumentError
    from fxc_env.policies.reference import ReferencePolicy

    teachers = {"reference": ReferencePolicy, "saturation_aware": SaturationAwarePolicy}
    if name not in teachers:
        raise ArgumentError(f"hyperparams: imitation teacher {name!r}; expected one of {tuple(teachers)}")
    return teachers[name](config)


def imitate_reference(model: Any, venv: Any, settings: dict[str, Any], seed: int) -> dict[str, float]:
    """Behaviour-clone the reference into ``model`` (an SB3 PPO) on ``venv``; returns the fit's figures.

    ``settings`` overrides :data:`DEFAULTS`. Deterministic for a given ``seed`` on the CPU.
    """
    import torch

    from fxc_env.config import config_of

    options = {**DEFAULTS, **settings}
    unknown = set(options) - set(DEFAULTS)
    if unknown:
        from fxc_env.core.validation import ArgumentError

        raise ArgumentError(f"hyperparams: unknown imitation key(s) {sorted(unknown)}; expected {sorted(DEFAULTS)}")
    config = config_of(venv, "imitation")
    reference = teacher_policy(str(options["teacher"]), config)
    rng = np.random.default_rng(seed)
    n_envs, episode = venv.num_envs, config.n_intervals
    steps = math.ceil(int(options["samples"]) / (n_envs * episode)) * episode  # whole episodes
    obs_size = config.layout.size
    observations = np.empty((steps, n_envs, obs_size), dtype=np.float32)
    targets = np.empty((steps, n_envs, config.action_size), dtype=np.float32)
    rewards = np.empty((steps, n_envs))
    dones = np.empty((steps, n_envs), dtype=bool)
    obs = venv.reset()
    for t in range(steps):
        target = reference(obs)
        observations[t], targets[t] = obs, target
        obs, rewards[t], dones[t], _ = venv.step(target + options["noise"] * rng.standard_normal(target.shape))
    gamma = float(model.gamma)
    returns = np.empty((steps, n_envs), dtype=np.float32)
    following = np.zeros(n_envs)
    for t in reversed(range(steps)):
        following = rewards[t] + gamma * following * ~dones[t]
        returns[t] = following

    policy = model.policy
    x = torch.as_tensor(observations.reshape(-1, obs_size))
    y = torch.as_tensor(targets.reshape(-1, config.action_size))
    g = torch.as_tensor(returns.reshape(-1, 1))
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
    return {
        "samples": float(steps * n_envs),
        "relative_action_rms_error": action_error,
        "value_rms_error": value_error,
    }
