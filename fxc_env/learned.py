"""A saved policy (stable-baselines3 model or RLlib checkpoint) as a policy on the local observation.

:class:`LearnedPolicy` (SB3) and :class:`RLlibPolicy` have the calling convention of
:class:`fxc_env.ReferencePolicy`: observations ``(..., obs_size)`` in, actions
``(..., 2 dim)`` out, deterministic. The model must have been trained on an environment
with the same observation layout (the same ``obs_slots``, ``dim`` and modes); a mismatch
raises an error naming the sizes. :func:`load_learned_policy` is the one place that decides
how a saved policy loads.
"""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError

#: The policy trained on ``paper_fig1`` that ships with the package (see ``training/README``).
PRETRAINED = "paper_fig1_ppo.zip"
#: The RLModule that ``fxc train --backend rllib`` shares between all agents.
RLLIB_MODULE = "shared"
#: RLlib checkpoints of a run: ``<run>/checkpoints/rllib_<timesteps>_steps/``.
RLLIB_CHECKPOINT_PATTERN = re.compile(r"rllib_(\d+)_steps")


def pretrained_path() -> Path:
    """Path of the shipped pretrained policy."""
    return Path(str(resources.files("fxc_env") / "pretrained" / PRETRAINED))


def load_model(path: str | Path) -> Any:
    """Load an SB3 PPO or SAC ``.zip`` on the CPU (the algorithm is read from the file)."""
    from stable_baselines3 import PPO, SAC

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"policy: no saved model at {path}")
    errors = []
    for algo in (PPO, SAC):
        try:
            return algo.load(path, device="cpu")
        except (ValueError, KeyError, TypeError, RuntimeError) as exc:  # wrong algorithm for this file
            errors.append(f"{algo.__name__}: {exc}")
    raise ArgumentError(f"policy: {path} is neither a PPO nor a SAC model ({'; '.join(errors)})")


class LearnedPolicy:
    """A trained SB3 model acting for every agent (parameter sharing), deterministically.

    Args:
        model: a loaded SB3 model, or the path of its ``.zip``.
        env: an fxc_env environment or EnvConfig whose observations the model will see;
            checked against the model's observation and action sizes when given.
        vecnormalize: path of VecNormalize statistics saved with the model, if any;
            observations are normalised with them before the model sees them.
    """

    def __init__(self, model: Any, env: Any = None, vecnormalize: str | Path | None = None) -> None:
        self.model = load_model(model) if isinstance(model, str | Path) else model
        self.obs_size = int(np.prod(self.model.observation_space.shape))
        self.action_size = int(np.prod(self.model.action_space.shape))
        self._normalizer = None
        if vecnormalize is not None:
            import pickle

            with open(vecnormalize, "rb") as handle:
                self._normalizer = pickle.load(handle)
        if env is not None:
            check_sizes(env, self.obs_size, self.action_size, "LearnedPolicy")

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for observations ``(..., obs_size)``."""
        obs = np.asarray(observation, dtype=np.float64)
        lead = obs.shape[:-1]
        flat = obs.reshape(-1, self.obs_size)
        if self._normalizer is not None:
            flat = self._normalizer.normalize_obs(flat)
        actions, _ = self.model.predict(flat, deterministic=True)
        return np.asarray(actions, dtype=np.float64).reshape((*lead, self.action_size))


def check_sizes(env: Any, obs_size: int, action_size: int, who: str) -> None:
    """Refuse an environment whose observation or action size differs from the model's."""
    from fxc_env.config import config_of

    config = config_of(env, who)
    if (config.layout.size, config.action_size) != (obs_size, action_size):
        raise ArgumentError(
            f"policy: the model takes observations of size {obs_size} and gives actions of size "
            f"{action_size}; this environment has {config.layout.size} and {config.action_size} "
            "(train with the same obs_slots, dim and modes, or pass obs_slots)"
        )


def rllib_checkpoint(path: str | Path) -> Path | None:
    """The RLlib algorithm checkpoint at ``path``: the directory itself, or a run directory's newest."""
    path = Path(path)
    if (path / "rllib_checkpoint.json").is_file():
        return path
    found = [
        (int(match.group(1)), candidate)
        for candidate in (path / "checkpoints").glob("rllib_*_steps")
        if (match := RLLIB_CHECKPOINT_PATTERN.fullmatch(candidate.name))
        and (candidate / "rllib_checkpoint.json").is_file()
    ]
    return max(found)[1] if found else None


class RLlibPolicy:
    """A trained RLlib module acting for every agent (parameter sharing), deterministically.

    Loads only the module (``learner_group/learner/rl_module/<module_id>`` of an algorithm
    checkpoint), on the CPU, without starting Ray; needs Ray RLlib installed. The action is
    the mode of the module's action distribution (the Gaussian's mean), clipped to the
    action space as during training.

    Args:
        checkpoint: an RLlib algorithm checkpoint directory, or a run directory of
            ``fxc train --backend rllib`` (its newest checkpoint).
        env: an fxc_env environment or EnvConfig, checked against the module's sizes.
        module_id: the module to load.
    """

    def __init__(self, checkpoint: str | Path, env: Any = None, module_id: str = RLLIB_MODULE) -> None:
        found = rllib_checkpoint(checkpoint)
        if found is None:
            raise FileNotFoundError(
                f"policy: no RLlib checkpoint at {checkpoint} (a directory with rllib_checkpoint.json, "
                "or a run directory with checkpoints/rllib_<timesteps>_steps/)"
            )
        module_dir = found / "learner_group" / "learner" / "rl_module" / module_id
        if not module_dir.is_dir():
            raise ArgumentError(f"policy: the RLlib checkpoint {found} has no module {module_id!r}")
        try:
            from ray.rllib.core.rl_module.rl_module import RLModule
        except ModuleNotFoundError as exc:
            raise ArgumentError(
                f"policy: {found} is an RLlib checkpoint, and Ray RLlib is not installed here; "
                'pip install "fxc-env[rllib]"'
            ) from exc
        self.checkpoint = found
        self.module = RLModule.from_checkpoint(module_dir)
        self.module.eval()
        self._distribution = self.module.get_inference_action_dist_cls()
        self.obs_size = int(np.prod(self.module.observation_space.shape))
        self.action_size = int(np.prod(self.module.action_space.shape))
        self._low = np.asarray(self.module.action_space.low, dtype=np.float64)
        self._high = np.asarray(self.module.action_space.high, dtype=np.float64)
        if env is not None:
            check_sizes(env, self.obs_size, self.action_size, "RLlibPolicy")

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for observations ``(..., obs_size)``."""
        import torch

        obs = np.asarray(observation, dtype=np.float32)
        lead = obs.shape[:-1]
        with torch.no_grad():
            out = self.module.forward_inference({"obs": torch.as_tensor(obs.reshape(-1, self.obs_size))})
            actions = self._distribution.from_logits(out["action_dist_inputs"]).to_deterministic().sample()
        actions = np.clip(actions.numpy().astype(np.float64), self._low, self._high)
        return actions.reshape((*lead, self.action_size))


def load_learned_policy(path: str | Path, env: Any = None) -> LearnedPolicy | RLlibPolicy:
    """A saved policy: an RLlib checkpoint or run directory, else an SB3 PPO/SAC ``.zip``.

    Raises ``FileNotFoundError`` naming ``policy`` when nothing is saved at ``path``.
    """
    path = Path(path)
    if path.is_dir():
        return RLlibPolicy(path, env)
    return LearnedPolicy(path, env)
