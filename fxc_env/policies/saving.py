"""Writing an SB3 policy file that loads without unpickling: :func:`save_model` and its record
(:data:`~fxc_env.policies.policy_files.METADATA_MEMBER`, read back by
:func:`~fxc_env.policies.policy_files.read_sb3_zip`); and the same record's ``env`` and ``domain``
beside an RLlib checkpoint (:func:`write_rllib_record`, read back by
:class:`~fxc_env.policies.learned.RLlibPolicy`).
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import training_domain
from fxc_env.policies.fit import training_settings

#: The plain-JSON member :func:`save_model` adds to an SB3 ``.zip``, and its format.
METADATA_MEMBER = "fxc_policy.json"
METADATA_FORMAT = "fxc_env.sb3_policy/1"
#: The format of the :data:`METADATA_MEMBER` file in an RLlib checkpoint directory (:func:`write_rllib_record`).
RLLIB_RECORD_FORMAT = "fxc_env.rllib_policy/1"


def policy_metadata(model: Any, env: Any = None) -> dict[str, Any]:
    """The :data:`METADATA_MEMBER` record of an SB3 ``model`` in memory (see the module).

    ``env``: the training environment (an fxc_env environment or EnvConfig); by default
    the one under ``model.get_env()`` (its VecNormalize statistics are recorded too).
    """
    from stable_baselines3.common.vec_env import VecNormalize
    from torch import nn

    policy = model.policy
    names = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu", nn.LeakyReLU: "leaky_relu"}
    activation_fn = getattr(policy, "activation_fn", None)
    policy_class = type(policy).__name__
    hidden = getattr(policy, "_hidden", None)  # the gain networks keep their widths here
    net_arch = list(hidden) if hidden is not None else getattr(policy, "net_arch", None)
    normalization = None
    vec = model.get_env()
    if isinstance(vec, VecNormalize) and vec.norm_obs:
        normalization = {
            "mean": np.asarray(vec.obs_rms.mean, dtype=float).tolist(),
            "var": np.asarray(vec.obs_rms.var, dtype=float).tolist(),
            "epsilon": float(vec.epsilon),
            "clip_obs": float(vec.clip_obs),
        }
    source = env if env is not None else innermost(vec)
    settings = domain = None
    if source is not None:
        try:
            settings, domain = training_settings(source), training_domain(source)
        except ArgumentError:
            settings = domain = None
    return {
        "format": METADATA_FORMAT,
        "algorithm": type(model).__name__,
        "policy_class": policy_class,
        "net_arch": net_arch,
        "activation": names.get(activation_fn, getattr(activation_fn, "__name__", None)),
        "features_extractor": _extractor_name(policy),
        "observation": _space_record(model.observation_space),
        "action": _space_record(model.action_space),
        "normalization": normalization,
        "num_timesteps": int(model.num_timesteps),
        "env": settings,
        "domain": domain,
    }


def _extractor_name(policy: Any) -> str | None:
    """The class name of the actor's features extractor (the policy's own, or SAC's actor's)."""
    for owner in (policy, getattr(policy, "actor", None)):
        extractor = getattr(owner, "features_extractor", None)
        if extractor is not None:
            return type(extractor).__name__
    return None


def innermost(vec: Any) -> Any:
    """The environment under SB3's VecEnv wrappers (``venv`` chains), or None."""
    while vec is not None and hasattr(vec, "venv"):
        vec = vec.venv
    return vec


def _space_record(space: Any) -> dict[str, Any]:
    return {
        "shape": [int(n) for n in space.shape],
        "low": np.asarray(space.low, dtype=float).ravel().tolist(),
        "high": np.asarray(space.high, dtype=float).ravel().tolist(),
    }


def add_metadata(path: str | Path, record: Mapping[str, Any]) -> Path:
    """Write ``record`` as :data:`METADATA_MEMBER` into the ``.zip`` at ``path``; the other members' bytes are kept."""
    path = Path(path)
    text = json.dumps(dict(record), indent=1, allow_nan=True)
    with zipfile.ZipFile(path) as archive:
        has_member = METADATA_MEMBER in archive.namelist()
    if not has_member:
        with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(METADATA_MEMBER, text)
        return path
    temporary = path.with_name(path.name + ".tmp")
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(temporary, "w") as target:
        for info in source.infolist():
            if info.filename != METADATA_MEMBER:
                target.writestr(info, source.read(info))
        target.writestr(METADATA_MEMBER, text, compress_type=zipfile.ZIP_DEFLATED)
    temporary.replace(path)
    return path


def save_model(model: Any, path: str | Path, env: Any = None) -> Path:
    """SB3's ``model.save(path)``, plus :data:`METADATA_MEMBER` (so the file loads without unpickling).

    Returns the path of the ``.zip`` (SB3 adds the suffix when it is missing).
    """
    path = Path(path)
    model.save(path)
    if path.suffix != ".zip":
        path = path.with_name(path.name + ".zip")
    return add_metadata(path, policy_metadata(model, env))


def write_rllib_record(checkpoint: str | Path, config: Any, module_id: str) -> Path:
    """Write :data:`METADATA_MEMBER` into the RLlib checkpoint directory ``checkpoint``: plain JSON.

    ``format`` (:data:`RLLIB_RECORD_FORMAT`), ``module`` (``module_id``, the module every agent
    shares), and as in an SB3 file's record ``env`` (:func:`~fxc_env.policies.fit.training_settings`)
    and ``domain`` (:func:`~fxc_env.policies.domain.training_domain`) of ``config``, the training
    environment (an EnvConfig or fxc_env environment). RLlib itself records neither. Returns the path.
    """
    record = {
        "format": RLLIB_RECORD_FORMAT,
        "module": module_id,
        "env": training_settings(config),
        "domain": training_domain(config),
    }
    path = Path(checkpoint) / METADATA_MEMBER
    path.write_text(json.dumps(record, indent=1) + "\n")
    return path
