"""A saved policy (stable-baselines3 model or RLlib checkpoint) as a policy on the local observation.

:class:`LearnedPolicy` (SB3) and :class:`RLlibPolicy` have the calling convention of
:class:`fxc_env.ReferencePolicy`: observations ``(..., obs_size)`` in, actions
``(..., 2 dim)`` out, deterministic. The model must have been trained on an environment
with the same observation layout (the same ``obs_slots``, ``dim`` and modes); a mismatch
raises an error naming the sizes. :func:`load_learned_policy` is the one place that decides
how a saved policy loads.
"""

from __future__ import annotations

import pickle
import re
import zipfile
import zlib
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError

#: The policies that ship with the package, by name (README, "Training learned policies"):
#: ``generalist`` (one policy for every graph family), ``saturated`` (inputs bounded by a
#: visible limit) and ``paper_fig1`` (the first release's, trained on the paper's graphs only).
#: ``pretrained`` means the generalist.
SHIPPED = {
    "pretrained": "generalist.zip",
    "generalist": "generalist.zip",
    "saturated": "saturated.zip",
    "paper_fig1": "paper_fig1_ppo.zip",
}
#: The schedule a shipped policy was trained on, where it is not the paper's.
SHIPPED_SCHEDULES = {"saturated": "uniform"}
#: The RLModule that ``fxc train --backend rllib`` shares between all agents.
RLLIB_MODULE = "shared"
#: RLlib checkpoints of a run: ``<run>/checkpoints/rllib_<timesteps>_steps/``.
RLLIB_CHECKPOINT_PATTERN = re.compile(r"rllib_(\d+)_steps")


#: What loading a damaged or foreign SB3 ``.zip`` raises: zipfile's and zlib's errors for a damaged
#: archive (SB3 wraps some in ``ValueError``), ``KeyError``/``AssertionError`` ("No data found") for
#: an archive without SB3's members, JSON and pickle errors for damaged members, ``EOFError`` and
#: torch's ``RuntimeError`` for truncated weights, ``TypeError``/``ValueError`` for the wrong algorithm.
MODEL_LOAD_ERRORS = (
    zipfile.BadZipFile,
    zlib.error,
    EOFError,
    KeyError,
    AssertionError,
    pickle.UnpicklingError,
    ValueError,
    TypeError,
    RuntimeError,
    OSError,
)


def pretrained_path(name: str = "paper_fig1") -> Path:
    """Path of a shipped policy (see :data:`SHIPPED`)."""
    return Path(str(resources.files("fxc_env") / "pretrained" / SHIPPED[name]))


def load_model(path: str | Path) -> Any:
    """Load an SB3 PPO or SAC ``.zip`` on the CPU (the algorithm is read from the file)."""
    from stable_baselines3 import PPO, SAC

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"policy: no saved model at {path}")
    if not path.is_file():
        raise ArgumentError(f"policy: {path} is not a file (expected a saved SB3 model, .zip)")
    if path.stat().st_size == 0:
        raise ArgumentError(f"policy: {path} is an empty file (expected a saved SB3 model, .zip)")
    if not zipfile.is_zipfile(path):
        raise ArgumentError(f"policy: {path} is not a zip archive (expected a saved SB3 model, .zip)")
    errors = []
    for algo in (PPO, SAC):
        try:
            return algo.load(path, device="cpu")
        except MODEL_LOAD_ERRORS as exc:  # the wrong algorithm for this file, or a damaged file
            errors.append(f"{algo.__name__}: {_summary(exc)}")
    raise ArgumentError(f"policy: {path} is neither a PPO nor a SAC model ({'; '.join(errors)})")


def _summary(exc: BaseException) -> str:
    """The exception's type and the first line of its message, at most 160 characters."""
    lines = str(exc).strip().splitlines()
    text = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


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
        try:
            self.module = RLModule.from_checkpoint(module_dir)
        except MODEL_LOAD_ERRORS as exc:
            raise ArgumentError(f"policy: cannot load the RLlib module in {module_dir} ({_summary(exc)})") from exc
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


class PerAxisPolicy:
    """A policy trained in one dimension acting on each axis of a ``dim``-dimensional environment.

    The paper's controller (eq. 11) acts on every axis alone, and so can a learned policy:
    for axis c the agent's normalized rows are rescaled by their own largest entry
    ``sigma_c`` (so the axis looks as it would alone, with local scale ``sigma_c s_i``), the
    one-dimensional policy acts, and its action, in units of ``sigma_c s_i``, is multiplied by
    ``sigma_c`` back into the environment's units of ``s_i`` (plan and accel actions are
    linear in the scale). The input-limit feature is recomputed for the axis's scale. Only
    for ``obs_mode="normalized"`` (raw observations carry no scale to split).
    """

    def __init__(self, policy: Any, config: Any) -> None:
        from fxc_env.config.layout import ObservationLayout

        self.policy = policy
        self.config = config
        self.layout = config.layout
        self.axis_layout = ObservationLayout(self.layout.slots, 1, limit_feature=self.layout.limit_feature)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        obs = self.layout.flat(observation)
        lead, dim = obs.shape[:-1], self.config.dim
        rows, mask, clock = self.layout.split(obs)  # rows (..., slots, 2, dim)
        sigma = np.max(np.abs(rows), axis=(-3, -2))  # (..., dim)
        scaled = rows / np.where(sigma > 0, sigma, 1.0)[..., None, None, :]
        axis_obs = np.empty((*lead, dim, self.axis_layout.size))
        axis_obs[..., : self.axis_layout.rows_end] = np.moveaxis(scaled, -1, -3).reshape((*lead, dim, -1))
        axis_obs[..., self.axis_layout.rows_end : self.axis_layout.mask_end] = mask[..., None, :]
        axis_obs[..., self.axis_layout.mask_end : self.axis_layout.clock_end] = clock[..., None, :]
        if self.layout.limit_feature:
            feature = obs[..., self.layout.clock_end]
            decades = feature / np.maximum(1.0 - np.abs(feature), 1e-300)  # invert l / (1 + |l|)
            with np.errstate(divide="ignore", invalid="ignore"):
                decades = decades[..., None] - np.log10(sigma)
                axis_obs[..., -1] = np.where(np.isfinite(decades), decades / (1.0 + np.abs(decades)), 1.0)
        actions = np.asarray(self.policy(axis_obs), dtype=np.float64)  # (..., dim, 2)
        actions = actions * sigma[..., None]
        return np.moveaxis(actions, -2, -1).reshape((*lead, 2 * dim))


def load_learned_policy(path: str | Path, env: Any = None) -> LearnedPolicy | RLlibPolicy | PerAxisPolicy:
    """A saved policy: a torch policy (``policy.pt`` or a ``--backend torchrl`` run directory), an RLlib
    checkpoint or run directory, else an SB3 PPO/SAC ``.zip``.

    A model trained in one dimension, loaded for a normalized environment with ``dim > 1``
    and the same neighbour slots, acts on every axis alone (:class:`PerAxisPolicy`).

    Raises ``FileNotFoundError`` naming ``policy`` when nothing is saved at ``path``, and
    :class:`~fxc_env.core.validation.ArgumentError` naming ``policy`` when the file is empty,
    damaged or not a PPO/SAC model, or the model does not fit ``env``.
    """
    path = Path(path)
    from fxc_env.policies.torch_policy import is_torch_policy, load_torch_policy

    load = load_torch_policy if is_torch_policy(path) else RLlibPolicy if path.is_dir() else LearnedPolicy
    if env is None:
        return load(path)
    from fxc_env.config import config_of
    from fxc_env.config.layout import ObservationLayout

    config = config_of(env, "policy")
    policy = load(path)
    axis_size = ObservationLayout(config.layout.slots, 1, limit_feature=config.layout.limit_feature).size
    if config.dim > 1 and config.obs_mode == "normalized" and (policy.obs_size, policy.action_size) == (axis_size, 2):
        return PerAxisPolicy(policy, config)
    check_sizes(config, policy.obs_size, policy.action_size, "policy")
    return policy
