"""An RLlib checkpoint (``fxc train --backend rllib``) as a policy on the local observation: :class:`RLlibPolicy`.

RLlib restores a module only by unpickling its checkpoint: refused unless ``trusted=True``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError
from fxc_env.policies.fit import check_fit
from fxc_env.policies.policy_files import MODEL_LOAD_ERRORS, TRUST_HINT, summary

#: The RLModule that ``fxc train --backend rllib`` shares between all agents.
RLLIB_MODULE = "shared"


#: RLlib checkpoints of a run: ``<run>/checkpoints/rllib_<timesteps>_steps/``.
RLLIB_CHECKPOINT_PATTERN = re.compile(r"rllib_(\d+)_steps")


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
        trusted: must be True: RLlib restores a module by unpickling its checkpoint
            (``class_and_ctor_args.pkl`` and friends), which runs any code a crafted
            checkpoint holds. Without it the checkpoint is refused and nothing in it is read.
    """

    def __init__(
        self, checkpoint: str | Path, env: Any = None, module_id: str = RLLIB_MODULE, *, trusted: bool = False
    ) -> None:
        found = rllib_checkpoint(checkpoint)
        if found is None:
            raise FileNotFoundError(
                f"policy: no RLlib checkpoint at {checkpoint} (a directory with rllib_checkpoint.json, "
                "or a run directory with checkpoints/rllib_<timesteps>_steps/)"
            )
        if not trusted:
            raise ArgumentError(
                f"policy: {found} is an RLlib checkpoint, which loads only by unpickling (running code from the "
                f"files); nothing in it was read. {TRUST_HINT}"
            )
        self.source = found
        self.training_settings: dict[str, Any] | None = None
        self.training_domain: dict[str, Any] | None = None  # an RLlib checkpoint records none
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
            raise ArgumentError(f"policy: cannot load the RLlib module in {module_dir} ({summary(exc)})") from exc
        self.module.eval()
        self._distribution = self.module.get_inference_action_dist_cls()
        self.obs_size = int(np.prod(self.module.observation_space.shape))
        self.action_size = int(np.prod(self.module.action_space.shape))
        self._low = np.asarray(self.module.action_space.low, dtype=np.float64)
        self._high = np.asarray(self.module.action_space.high, dtype=np.float64)
        if env is not None:
            check_fit(self, env, "RLlibPolicy")

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
