"""A saved stable-baselines3 model as a policy on the local observation.

:class:`LearnedPolicy` has the calling convention of :class:`fxc_env.ReferencePolicy`:
observations ``(..., obs_size)`` in, actions ``(..., 2 dim)`` out, deterministic. The
model must have been trained on an environment with the same observation layout (the
same ``obs_slots``, ``dim`` and modes); a mismatch raises an error naming the sizes.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

#: The policy trained on ``paper_fig1`` that ships with the package (see ``training/README``).
PRETRAINED = "paper_fig1_ppo.zip"


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
    raise ValueError(f"policy: {path} is neither a PPO nor a SAC model ({'; '.join(errors)})")


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
            from fxc_env.config import config_of

            config = config_of(env, "LearnedPolicy")
            if (config.layout.size, config.action_size) != (self.obs_size, self.action_size):
                raise ValueError(
                    f"policy: the model takes observations of size {self.obs_size} and gives actions of size "
                    f"{self.action_size}; this environment has {config.layout.size} and {config.action_size} "
                    "(train with the same obs_slots, dim and modes, or pass obs_slots)"
                )

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for observations ``(..., obs_size)``."""
        obs = np.asarray(observation, dtype=np.float64)
        lead = obs.shape[:-1]
        flat = obs.reshape(-1, self.obs_size)
        if self._normalizer is not None:
            flat = self._normalizer.normalize_obs(flat)
        actions, _ = self.model.predict(flat, deterministic=True)
        return np.asarray(actions, dtype=np.float64).reshape((*lead, self.action_size))
