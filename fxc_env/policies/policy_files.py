"""Saved SB3 policies read without running code from them (the checks of what they fit: :mod:`~fxc_env.policies.fit`).

A stable-baselines3 ``.zip`` holds ``data`` (JSON, some of whose entries are cloudpickled
objects: ``policy_class``, ``lr_schedule``, the spaces...), ``policy.pth`` (the network's state
dict) and ``policy.optimizer.pth``. SB3's own ``load`` unpickles ``data``, so a crafted file
runs code. :func:`read_sb3_zip` unpickles nothing: it reads the readable JSON (SB3 writes the
readable fields of each pickled object next to it, e.g. ``observation_space``'s ``_shape``,
``low`` and ``high``, and ``policy_kwargs`` as plain JSON when it is), rebuilds one of the
networks it knows (:data:`KNOWN_POLICIES`) and loads the weights with
``torch.load(..., weights_only=True)``. What only a pickle would tell is written as plain JSON
beside the weights by :func:`save_model`: the member :data:`METADATA_MEMBER` (its fields: docs:
training.md, "The metadata member").
"""

from __future__ import annotations

import io
import json
import pickle
import re
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError, real
from fxc_env.policies.fit import CHECKED_SETTINGS, check_settings, settings_from_env_kwargs, training_settings  # noqa: F401
from fxc_env.policies.records import checked_domain, file_box, file_number, file_tensor
from fxc_env.policies.saving import METADATA_FORMAT, METADATA_MEMBER, add_metadata, policy_metadata, save_model  # noqa: F401

#: Policy classes whose network :func:`read_sb3_zip` rebuilds, by algorithm.
KNOWN_POLICIES = {"PPO": ("ActorCriticPolicy", "GainScheduledPolicy", "GatedGainPolicy"), "SAC": ("SACPolicy",)}
#: The modules those classes live in (read from ``data``'s ``policy_class.__module__``).
KNOWN_MODULES = {
    "stable_baselines3.common.policies": ("ActorCriticPolicy",),
    "stable_baselines3.sac.policies": ("SACPolicy",),
    "fxc_env.policies.gain_network": ("GainScheduledPolicy", "GatedGainPolicy"),
    "fxc_env.gain_policy": ("GainScheduledPolicy", "GatedGainPolicy"),  # files saved before the layer folders
}
#: The parameters each policy class's ``policy.pth`` may hold (a Flatten features extractor has none).
PARAMETER_PREFIXES = {
    "ActorCriticPolicy": (
        "mlp_extractor.policy_net.",
        "mlp_extractor.value_net.",
        "action_net.",
        "value_net.",
        "log_std",
    ),
    "GainScheduledPolicy": ("mlp_extractor.", "value_net.", "log_std"),
    "GatedGainPolicy": ("mlp_extractor.", "value_net.", "log_std"),
    "SACPolicy": ("actor.latent_pi.", "actor.mu.", "actor.log_std.", "critic.", "critic_target."),
}
#: Activations by name (SB3's defaults: tanh for actor-critic policies, relu for SAC).
ACTIVATION_NAMES = ("tanh", "relu", "elu", "leaky_relu")
TRUST_HINT = "pass trusted=True (fxc: --trust-policy-file) only if you trust whoever made the file"


# --------------------------------------------------------------------------------- reading a zip
class SavedModel:
    """An SB3 PPO or SAC model read by :func:`read_sb3_zip`: enough of SB3's model for acting.

    Attributes:
        path: the ``.zip`` it was read from.
        algorithm: ``"PPO"`` or ``"SAC"``.
        policy_class: the SB3 policy class's name (:data:`KNOWN_POLICIES`).
        policy: the actor network (a torch module, float32): flat observations
            ``(batch, obs_size)`` to the action mean ``(batch, action_size)`` (before SAC's tanh).
        observation_space, action_space: gymnasium ``Box`` spaces rebuilt from plain values.
        num_timesteps: the timesteps it was trained for.
        normalization: VecNormalize's observation statistics, or None.
        training: the training environment's settings (:func:`training_settings`), or None
            for a file without :data:`METADATA_MEMBER`.
        domain: the training domain (:func:`fxc_env.policies.domain.training_domain`), or None
            for a file that records none.
        metadata: :data:`METADATA_MEMBER`'s record, or None.
    """

    def __init__(self, path: Path, spec: dict[str, Any], policy: Any, data: Mapping[str, Any]) -> None:
        from gymnasium import spaces

        self.path = path
        self.algorithm = spec["algorithm"]
        self.policy_class = spec["policy_class"]
        self.policy = policy
        self.squash = self.algorithm == "SAC"

        def box(record: Mapping[str, Any]) -> Any:
            low, high = (np.asarray(record[end], dtype=np.float64).reshape(record["shape"]) for end in ("low", "high"))
            return spaces.Box(low, high, dtype=np.float64)

        self.observation_space, self.action_space = box(spec["observation"]), box(spec["action"])
        self.num_timesteps = int(data.get("num_timesteps", 0) or 0)
        self.normalization = spec.get("normalization")
        self.training = spec.get("env")
        self.domain = spec.get("domain")
        self.metadata = spec.get("metadata")

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
        """SB3's ``predict`` for a Box policy, deterministic: ``(actions (batch, action_size), None)``.

        The same arithmetic as SB3: the observation as float32, the actor's mean, then for
        PPO a clip to the action space, for SAC ``tanh`` and the affine map onto it.
        """
        import torch

        if not deterministic:
            raise ArgumentError("deterministic: a SavedModel acts deterministically only (deterministic=True)")
        obs = np.asarray(observation).reshape((-1, *self.observation_space.shape))
        with torch.no_grad():
            out = self.policy(torch.as_tensor(obs).float())
            if self.squash:
                out = torch.tanh(out)
        actions = out.numpy().reshape((-1, *self.action_space.shape))
        low, high = self.action_space.low, self.action_space.high
        if self.squash:
            return low + (0.5 * (actions + 1.0) * (high - low)), None
        return np.clip(actions, low, high), None


def read_metadata(path: str | Path) -> dict[str, Any] | None:
    """The :data:`METADATA_MEMBER` record of the ``.zip`` at ``path`` (plain JSON), or None if it has none or is unreadable."""
    try:
        with zipfile.ZipFile(path) as archive:
            if METADATA_MEMBER not in archive.namelist():
                return None
            record = json.loads(archive.read(METADATA_MEMBER))
    except (zipfile.BadZipFile, OSError, ValueError):
        return None
    return record if isinstance(record, dict) and record.get("format") == METADATA_FORMAT else None


def checked_zip_path(path: str | Path) -> Path:
    """``path`` as a Path once it names a non-empty zip archive; else the error naming ``policy``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"policy: no saved model at {path}")
    if not path.is_file():
        raise ArgumentError(f"policy: {path} is not a file (expected a saved SB3 model, .zip)")
    if path.stat().st_size == 0:
        raise ArgumentError(f"policy: {path} is an empty file (expected a saved SB3 model, .zip)")
    if not zipfile.is_zipfile(path):
        raise ArgumentError(f"policy: {path} is not a zip archive (expected a saved SB3 model, .zip)")
    return path


def read_sb3_zip(path: str | Path) -> SavedModel:
    """Read an SB3 PPO/SAC ``.zip`` without unpickling anything (see the module).

    Raises ``FileNotFoundError`` when nothing is at ``path``, and :class:`ArgumentError` naming
    ``policy`` and the path when the file is not an SB3 model, is damaged, holds weights that
    are not plain tensors, or uses a network this loader cannot rebuild (a custom policy
    class or features extractor, or an activation recorded only in a pickle); such files load
    with ``trusted=True`` (:func:`fxc_env.policies.learned.load_model`), which runs SB3's loader.
    """
    import torch

    path = checked_zip_path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            missing = [m for m in ("data", "policy.pth") if m not in names]
            if missing:
                raise ArgumentError(
                    f"policy: {path} is not a saved SB3 model (no {' or '.join(missing)} in the archive)"
                )
            data = json.loads(archive.read("data"))
            metadata = json.loads(archive.read(METADATA_MEMBER)) if METADATA_MEMBER in names else None
            weights_bytes = archive.read("policy.pth")
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, UnicodeDecodeError) as exc:
        if isinstance(exc, ArgumentError):
            raise
        raise ArgumentError(f"policy: {path} is a damaged SB3 model ({summary(exc)})") from exc
    if not isinstance(data, dict):
        raise ArgumentError(f"policy: {path} is not a saved SB3 model (its data is not a JSON object)")
    try:
        weights = torch.load(io.BytesIO(weights_bytes), map_location="cpu", weights_only=True)
    # torch's UnpicklingError for anything but plain tensors, RuntimeError/EOFError when damaged
    except Exception as exc:
        raise ArgumentError(
            f"policy: {path}: policy.pth is not a plain state dict of tensors ({summary(exc)}); "
            f"nothing in it was run. {TRUST_HINT}"
        ) from exc
    if not isinstance(weights, Mapping) or not all(isinstance(v, torch.Tensor) for v in weights.values()):
        raise ArgumentError(f"policy: {path}: policy.pth is not a state dict of tensors")
    try:
        spec = _architecture(path, data, metadata, weights)
        _check_numbers(path, spec, data, weights)
        return SavedModel(path, spec, _build(path, spec, weights), data)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        if isinstance(exc, ArgumentError):
            raise
        raise ArgumentError(f"policy: {path}: its model description is malformed ({summary(exc)})") from exc


def _check_numbers(path: Path, spec: dict[str, Any], data: Mapping[str, Any], weights: Mapping[str, Any]) -> None:
    """Refuse, naming the file and the field, a malformed domain record, space, ``num_timesteps`` or a non-finite
    weight: every record of the file checked in one pass (:mod:`fxc_env.policies.records`) before anything is built."""
    spec["domain"] = checked_domain(spec["domain"], path)
    file_box(path, "observation", spec["observation"], bounded=False)
    file_box(path, "action", spec["action"], bounded=True)
    for record in (data, spec.get("metadata") or {}):  # SB3's count, and the count fxc_policy.json records
        file_number(path, "num_timesteps", record.get("num_timesteps", 0), integral=True, minimum=0)
    for name, tensor in weights.items():
        file_tensor(path, f"policy.pth {name}", tensor)


def summary(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    text = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def _readable_space(path: Path, data: Mapping[str, Any], name: str) -> dict[str, Any]:
    """A Box space's shape, low and high from the readable fields SB3 writes beside its pickle."""
    space = data.get(name)
    if not isinstance(space, Mapping) or "Box" not in str(space.get(":type:", "")):
        raise ArgumentError(f"policy: {path} records no readable Box {name} (a non-Box space); {TRUST_HINT}")
    try:
        shape = [int(n) for n in space["_shape"]]
        bounds = {
            key: [float(v) for v in str(space[key]).replace("[", " ").replace("]", " ").split()]
            for key in ("low", "high")
        }
    except (KeyError, TypeError, ValueError) as exc:
        raise ArgumentError(f"policy: {path}: cannot read the {name} from its plain fields ({summary(exc)})") from exc
    size = int(np.prod(shape))
    if any(len(v) != size for v in bounds.values()):
        raise ArgumentError(f"policy: {path}: the {name}'s bounds do not have {size} entries")
    return {"shape": shape, **bounds}


def _class_name(path: Path, data: Mapping[str, Any]) -> str:
    """The policy class's name from ``policy_class``'s readable fields (``__module__`` and its methods' names)."""
    entry = data.get("policy_class")
    module = entry.get("__module__") if isinstance(entry, Mapping) else None
    names = {
        found.group(1)
        for value in (entry.values() if isinstance(entry, Mapping) else ())
        if isinstance(value, str) and (found := re.match(r"<function (\w+)\.\w+ at 0x", value))
    }
    known = KNOWN_MODULES.get(str(module), ())
    if len(names) == 1 and next(iter(names)) in known:
        return next(iter(names))
    label = f"{module}.{'/'.join(sorted(names)) or '?'}" if module else "an unreadable policy class"
    raise ArgumentError(
        f"policy: {path} uses {label}, which this loader cannot rebuild without running code from the file "
        f"(it rebuilds {', '.join(c for v in KNOWN_POLICIES.values() for c in v)}); {TRUST_HINT}"
    )


def _recorded_spec(path: Path, metadata: Any) -> dict[str, Any]:
    """What to rebuild, from the file's :data:`METADATA_MEMBER` record."""
    if not isinstance(metadata, Mapping) or metadata.get("format") != METADATA_FORMAT:
        raise ArgumentError(f"policy: {path}: {METADATA_MEMBER} is not a {METADATA_FORMAT!r} record")
    spec = {key: metadata.get(key) for key in ("algorithm", "policy_class", "net_arch", "activation")}
    spec.update(
        observation=metadata.get("observation"),
        action=metadata.get("action"),
        normalization=metadata.get("normalization"),
        env=metadata.get("env"),
        domain=metadata.get("domain"),  # checked with the file's other records (_check_numbers)
        metadata=dict(metadata),
    )
    for key in ("observation", "action"):
        if not isinstance(spec[key], Mapping) or not {"shape", "low", "high"} <= set(spec[key]):
            raise ArgumentError(f"policy: {path}: {METADATA_MEMBER} has no {key} shape and bounds")
    extractor = metadata.get("features_extractor", "FlattenExtractor")
    if extractor != "FlattenExtractor":
        raise ArgumentError(f"policy: {path}: features extractor {extractor!r} is not rebuilt; {TRUST_HINT}")
    return spec


def _plain_spec(path: Path, data: Mapping[str, Any], weights: Mapping[str, Any]) -> dict[str, Any]:
    """What to rebuild, from SB3's plain-JSON ``data`` (refused where it holds a pickle)."""
    algorithm = "SAC" if any(k.startswith("actor.mu.") for k in weights) else "PPO"
    kwargs = data.get("policy_kwargs", {})
    if not isinstance(kwargs, Mapping) or ":serialized:" in kwargs:
        raise ArgumentError(
            f"policy: {path}: its policy_kwargs are recorded only as a pickle (a class such as activation_fn "
            f"or a features extractor), and the file has no {METADATA_MEMBER}; re-save it with "
            f"fxc_env.policies.policy_files.save_model, or {TRUST_HINT}"
        )
    plain_options = {"net_arch", "log_std_init", "ortho_init", "squash_output", "use_expln", "n_critics", "use_sde"}
    plain_options |= {"clip_mean", "share_features_extractor", "normalize_images"}
    unknown = sorted(set(kwargs) - plain_options)
    unknown += [key for key in ("squash_output", "use_sde") if kwargs.get(key)]
    if data.get("use_sde"):
        unknown.append("use_sde")
    if unknown:
        raise ArgumentError(f"policy: {path}: policy options {unknown} are not rebuilt; {TRUST_HINT}")
    default_arch = [256, 256] if algorithm == "SAC" else [64, 64]
    return {
        "algorithm": algorithm,
        "policy_class": _class_name(path, data),
        "net_arch": kwargs.get("net_arch", default_arch),
        "activation": "relu" if algorithm == "SAC" else "tanh",
        "observation": _readable_space(path, data, "observation_space"),
        "action": _readable_space(path, data, "action_space"),
        "normalization": None,
        "env": None,
        "domain": None,
        "metadata": None,
    }


def _architecture(path: Path, data: Mapping[str, Any], metadata: Any, weights: Mapping[str, Any]) -> dict[str, Any]:
    """What to rebuild: from :data:`METADATA_MEMBER` when the file has it, else from ``data``'s plain JSON."""
    spec = _recorded_spec(path, metadata) if metadata is not None else _plain_spec(path, data, weights)
    if spec["algorithm"] not in KNOWN_POLICIES or spec["policy_class"] not in KNOWN_POLICIES[spec["algorithm"]]:
        raise ArgumentError(
            f"policy: {path}: {spec['algorithm']} with {spec['policy_class']} is not a network this loader rebuilds "
            f"({KNOWN_POLICIES}); {TRUST_HINT}"
        )
    allowed = PARAMETER_PREFIXES[spec["policy_class"]]
    foreign = sorted(k for k in weights if not k.startswith(allowed))
    if foreign:
        raise ArgumentError(
            f"policy: {path}: policy.pth holds parameters {foreign[:4]} that {spec['policy_class']} does not have "
            f"(a custom features extractor or network?); {TRUST_HINT}"
        )
    if spec["activation"] not in ACTIVATION_NAMES:
        raise ArgumentError(f"policy: {path}: activation {spec['activation']!r}; expected one of {ACTIVATION_NAMES}")
    return spec


def _actor_widths(net_arch: Any, key: str) -> list[int]:
    """The actor's hidden widths from SB3's ``net_arch`` (a list, or a dict with ``pi``)."""
    if isinstance(net_arch, Mapping):
        net_arch = net_arch.get(key, [])
    return [int(w) for w in net_arch]


#: SB3's actor parameters -> :class:`~fxc_env.policies.networks.MeanActor`'s (PPO's and SAC's).
_ACTOR_PREFIXES = {
    "ActorCriticPolicy": {"mlp_extractor.policy_net.": "latent.", "action_net.": "mean."},
    "SACPolicy": {"actor.latent_pi.": "latent.", "actor.mu.": "mean."},
}


def _renamed(weights: Mapping[str, Any], prefixes: Mapping[str, str]) -> dict[str, Any]:
    """The entries of ``weights`` under a prefix of ``prefixes``, under its new prefix."""
    return {new + k[len(old) :]: v for old, new in prefixes.items() for k, v in weights.items() if k.startswith(old)}


def _build(path: Path, spec: dict[str, Any], weights: Mapping[str, Any]) -> Any:
    """The actor network of ``spec`` with ``weights`` loaded (strictly: every actor key, no other)."""
    from torch import nn

    from fxc_env.policies.networks import GainActor, MeanActor, mlp

    obs_size = int(np.prod(spec["observation"]["shape"]))
    action_size = int(np.prod(spec["action"]["shape"]))
    cls = spec["policy_class"]
    if cls in ("ActorCriticPolicy", "SACPolicy"):
        widths = _actor_widths(spec["net_arch"], "pi")
        module: nn.Module = MeanActor(
            mlp(obs_size, None, widths, spec["activation"]), nn.Linear(widths[-1] if widths else obs_size, action_size)
        )
        state = _renamed(weights, _ACTOR_PREFIXES[cls])
    else:  # the gain-scheduled networks of fxc_env.policies.gain_network
        net_arch = spec["net_arch"]
        hidden = tuple(int(w) for w in net_arch) if isinstance(net_arch, list | tuple) else (64, 64)
        from fxc_env.policies.gain_network import GainScheduledExtractor, GatedGainExtractor

        extractor_class = GatedGainExtractor if cls == "GatedGainPolicy" else GainScheduledExtractor
        try:
            extractor = extractor_class(obs_size, hidden)
        except ValueError as exc:
            raise ArgumentError(f"policy: {path}: {exc}") from exc
        module = GainActor(extractor)
        state = _renamed(weights, {"mlp_extractor.": "extractor."})
    try:
        module.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ArgumentError(
            f"policy: {path}: the weights in policy.pth do not fit {spec['algorithm']} {cls} with net_arch "
            f"{spec['net_arch']} ({summary(exc)})"
        ) from exc
    return module.eval().requires_grad_(False)


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


def read_normalization(path: str | Path, obs_size: int, *, trusted: bool = False) -> dict[str, Any]:
    """VecNormalize's observation statistics from ``path``: ``{"mean", "var", "epsilon", "clip_obs"}``.

    A ``.json`` or ``.npz`` (``allow_pickle=False``) holds plain arrays; anything else is taken
    for VecNormalize's pickle, read only with ``trusted=True`` (unpickling runs the file's code).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"vecnormalize: no statistics file at {path}")
    try:
        if path.suffix == ".json":
            record = dict(json.loads(path.read_text()))
        elif path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as arrays:
                record = {key: arrays[key] for key in arrays.files}
        elif trusted:
            with open(path, "rb") as handle:
                normalizer = pickle.load(handle)
            record = {
                "mean": normalizer.obs_rms.mean,
                "var": normalizer.obs_rms.var,
                "epsilon": normalizer.epsilon,
                "clip_obs": normalizer.clip_obs,
            }
        else:
            raise ArgumentError(
                f"vecnormalize: {path} is a pickle (VecNormalize.save), and unpickling runs code from the file; "
                f"nothing in it was run. Give the statistics as .json or .npz (mean, var, epsilon, clip_obs), or "
                f"{TRUST_HINT}"
            )
    except (KeyError, TypeError, ValueError, OSError) as exc:
        if isinstance(exc, ArgumentError):
            raise
        raise ArgumentError(f"vecnormalize: cannot read statistics from {path} ({summary(exc)})") from exc
    return normalization_stats(record, obs_size, path)


def normalization_stats(record: Any, obs_size: int, source: Any) -> dict[str, Any]:
    """VecNormalize's statistics as float64 arrays ``mean``, ``var`` ``(obs_size,)`` and floats ``epsilon``, ``clip_obs``."""
    try:
        stats = {
            "mean": np.asarray(record["mean"], dtype=np.float64),
            "var": np.asarray(record["var"], dtype=np.float64),
            "epsilon": float(record.get("epsilon", 1e-8)),
            "clip_obs": float(record.get("clip_obs", 10.0)),
        }
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ArgumentError(f"vecnormalize: cannot read statistics from {source} ({summary(exc)})") from exc
    if stats["mean"].shape != (obs_size,) or stats["var"].shape != (obs_size,):
        raise ArgumentError(
            f"vecnormalize: {source} holds statistics of shape {stats['mean'].shape}; the model takes ({obs_size},)"
        )
    if not (np.all(np.isfinite(stats["mean"])) and np.all(np.isfinite(stats["var"])) and np.all(stats["var"] >= 0)):
        raise ArgumentError(f"vecnormalize: {source}: mean and var must be finite, var >= 0 (no NaN or inf)")
    for key in ("epsilon", "clip_obs"):
        real(f"vecnormalize: {source}: {key}", stats[key], positive=True)
    return stats
