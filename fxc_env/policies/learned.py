"""A saved policy (stable-baselines3 model, torch policy, RLlib checkpoint, gain schedule) as a policy on the
local observation: :func:`load_learned_policy` is the one place that decides how a saved policy loads.

The readers: :class:`LearnedPolicy` (an SB3 ``.zip``, read by :mod:`fxc_env.policies.policy_files`
without unpickling), :mod:`~fxc_env.policies.torch_policy`, :class:`RLlibPolicy`
(only with ``trusted=True``: RLlib unpickles) and :mod:`~fxc_env.policies.interval_gains`. Every one
has the calling convention of :class:`fxc_env.ReferencePolicy` (observations ``(..., obs_size)`` in,
actions ``(..., 2 dim)`` out, deterministic) and must fit the environment it is given
(:mod:`~fxc_env.policies.fit`: sizes, the settings it was trained for, its training domain);
:mod:`~fxc_env.policies.fit` also lets it act on another number of neighbour slots or per axis.
**Loading runs no code from the file** unless ``trusted=True`` (docs: training.md, "Training learned policies").
"""

from __future__ import annotations

import json
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.config import config_of, make_config
from fxc_env.config.layout import ObservationLayout
from fxc_env.core.validation import ArgumentError, boolean
from fxc_env.policies.domain import check_domain, domain_from_settings, training_domain
from fxc_env.policies.fit import (  # noqa: F401
    PerAxisPolicy,
    PolicyAdaptedWarning,
    SlotAdaptedPolicy,
    adapt_slots,
    architecture_of,
    check_fit,
    check_settings,
    check_width,
    trained_slots,
    training_settings,
)
from fxc_env.policies.interval_gains import IntervalGainPolicy, read_interval_gains
from fxc_env.policies.policy_files import (
    MODEL_LOAD_ERRORS,
    TRUST_HINT,
    checked_zip_path,
    normalization_stats,
    read_metadata,
    read_normalization,
    read_sb3_zip,
    summary,
)
from fxc_env.policies.protocol import Policy
from fxc_env.policies.records import checked_domain
from fxc_env.policies.saving import METADATA_MEMBER, RLLIB_RECORD_FORMAT, innermost

#: The policies that ship with the package, by name (docs: training.md, "Training learned policies"):
#: ``generalist`` (one policy for every graph family), ``saturated`` (inputs bounded by a
#: visible limit) and ``paper_fig1`` (the first release's, trained on the paper's graphs only).
#: ``pretrained`` means the generalist.
SHIPPED = {
    "pretrained": "generalist.zip",
    "generalist": "generalist.zip",
    "saturated": "saturated.zip",
    "paper_fig1": "paper_fig1_ppo.zip",
    "rings": "rings.npz",  # a gain schedule (fxc_env.policies.interval_gains), not an SB3 model
    "rings_gru": "rings_gru.pt",  # a recurrent torch policy (fxc_env.policies.torch_memory)
    "rings_scratch": "rings_scratch.npz",  # a gain schedule learned from scratch (fxc_env.training.recipes.rings_scratch)
    "agnostic": "agnostic.npz",  # one gain schedule for any graph, not told the graph (fxc_env.training.recipes.agnostic)
    "ppo_rings20": "ppo_rings20.pt",  # torch PPO from scratch on the task rings20-v2 (training/recipes/rings20_v2.yml)
    "diff_rings20": "diff_rings20.pt",  # analytic policy gradients from scratch on rings20-v2 (same file)
}
#: The schedule a shipped policy was trained on, where it is not the paper's.
SHIPPED_SCHEDULES = {"saturated": "uniform"}


def pretrained_path(name: str = "paper_fig1") -> Path:
    """Path of a shipped policy (see :data:`SHIPPED`)."""
    return Path(str(resources.files("fxc_env") / "pretrained" / SHIPPED[name]))


def load_model(path: str | Path, *, trusted: bool = False) -> Any:
    """Load an SB3 PPO or SAC ``.zip`` on the CPU (the algorithm is read from the file).

    By default nothing in the file is unpickled: the result is a
    :class:`~fxc_env.policies.policy_files.SavedModel` (spaces, ``num_timesteps``, the actor
    network, ``predict``) rebuilt from its plain JSON and ``weights_only`` tensors. With
    ``trusted=True`` it is SB3's own ``PPO.load``/``SAC.load`` (the whole model, optimiser
    included, for networks the safe reader does not rebuild), which unpickles the file's
    ``data`` and so runs any code a crafted file holds: only for files you trust.
    """
    if not trusted:
        return read_sb3_zip(path)
    from stable_baselines3 import PPO, SAC

    path = checked_zip_path(path)
    errors = []
    for algo in (PPO, SAC):
        try:
            return algo.load(path, device="cpu")
        except MODEL_LOAD_ERRORS as exc:  # the wrong algorithm for this file, or a damaged file
            errors.append(f"{algo.__name__}: {summary(exc)}")
    raise ArgumentError(f"policy: {path} is neither a PPO nor a SAC model ({'; '.join(errors)})")


class LearnedPolicy(Policy):
    """A trained SB3 model acting for every agent (parameter sharing), deterministically.

    Args:
        model: a loaded SB3 model (or :class:`~fxc_env.policies.policy_files.SavedModel`), or
            the path of its ``.zip`` (read without unpickling unless ``trusted``).
        env: an fxc_env environment or EnvConfig whose observations the model will see;
            checked against the model's sizes and, where the model records them, the settings
            it was trained for (see the module) when given.
        vecnormalize: VecNormalize statistics for the observations, if any: a ``.json`` or
            ``.npz`` with ``mean``, ``var`` (and ``epsilon``, ``clip_obs``; SB3's defaults 1e-8
            and 10), or VecNormalize's pickle (``.pkl``, only with ``trusted=True``). A model
            saved with its statistics in ``fxc_policy.json`` uses those without this argument.
        trusted: allow formats that unpickle (SB3's loader, VecNormalize's pickle); they run
            any code a crafted file holds.
        allow_out_of_domain: run in an ``env`` outside the training domain the model records,
            with an :class:`~fxc_env.policies.domain.OutOfDomainWarning` naming every difference
            (refused by name otherwise; :func:`fxc_env.policies.domain.check_domain`).

    Attributes:
        training_settings: the settings of the environment it was trained on
            (:func:`fxc_env.policies.policy_files.training_settings`), or None when the file
            records none.
        training_domain: where it was trained (:func:`fxc_env.policies.domain.training_domain`;
            for a file that records only its settings, the N, K, T_s, schedule and limits they
            hold), or None.
    """

    def __init__(
        self,
        model: Any,
        env: Any = None,
        vecnormalize: str | Path | None = None,
        *,
        trusted: bool = False,
        allow_out_of_domain: bool = False,
    ) -> None:
        self.source = model if isinstance(model, str | Path) else None
        self.model = load_model(model, trusted=trusted) if isinstance(model, str | Path) else model
        self.obs_size = int(np.prod(self.model.observation_space.shape))
        self.action_size = int(np.prod(self.model.action_space.shape))
        recorded = hasattr(self.model, "training")  # a SavedModel's record, else the in-memory model's env
        self.training_settings = self.model.training if recorded else _recorded(self.model, training_settings)
        self._stats = getattr(self.model, "normalization", None)
        self.training_domain = (
            getattr(self.model, "domain", None)
            or _recorded(self.model, training_domain)
            or domain_from_settings(self.training_settings)
        )
        if self.source is not None and trusted:  # SB3's loader: the plain record still says how it was trained
            record = read_metadata(self.source) or {}
            self.training_settings = self.training_settings or record.get("env")
            recorded_domain = checked_domain(record.get("domain"), self.source)
            self.training_domain = recorded_domain or domain_from_settings(self.training_settings)
            self._stats = self._stats or record.get("normalization")
        if self._stats is not None:
            self._stats = normalization_stats(self._stats, self.obs_size, self.source)
        if vecnormalize is not None:
            self._stats = read_normalization(vecnormalize, self.obs_size, trusted=trusted)
        if env is not None:
            check_fit(self, env, "LearnedPolicy", allow_out_of_domain=allow_out_of_domain)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for flat observations ``(..., obs_size)``."""
        lead = obs.shape[:-1]
        flat = obs.reshape(-1, self.obs_size)
        if self._stats is not None:
            s = self._stats
            flat = np.clip((flat - s["mean"]) / np.sqrt(s["var"] + s["epsilon"]), -s["clip_obs"], s["clip_obs"])
        actions, _ = self.model.predict(flat, deterministic=True)
        return np.asarray(actions, dtype=np.float64).reshape((*lead, self.action_size))


def _recorded(model: Any, read: Any) -> Any:
    """``read`` (:func:`training_settings`, :func:`training_domain`) of the environment an in-memory SB3 model
    trained on (under its VecEnv wrappers), or None (a SavedModel has none: it records them)."""
    get_env = None if hasattr(model, "training") else getattr(model, "get_env", None)
    vec = innermost(get_env()) if callable(get_env) else None
    try:
        return None if vec is None else read(vec)
    except (ArgumentError, AttributeError):
        return None


def load_learned_policy(
    path: str | Path, env: Any = None, *, trusted: bool = False, allow_out_of_domain: bool = False
) -> LearnedPolicy | RLlibPolicy | PerAxisPolicy:
    """A saved policy: a torch policy (``policy.pt`` or a ``--backend torch`` run directory), an RLlib
    checkpoint or run directory (only with ``trusted=True``), else an SB3 PPO/SAC ``.zip``.

    Nothing in the file is unpickled unless ``trusted`` (see the module): ``fxc evaluate``
    and ``fxc benchmark`` should pass it only for ``--trust-policy-file``. With ``env``, the
    policy must fit it: sizes, and the training settings the file records (modes, input-limit
    feature, agent model, dim). Another ``obs_slots`` (and so any in-degree) is
    adapted (:func:`adapt_slots`, :class:`SlotAdaptedPolicy`): exactly for fewer rows than
    trained with, by the gain networks' per-row structure for more (a warning), refused by
    name for a fixed-width network whose width the environment's in-degree exceeds. A model
    trained in one dimension, loaded for a normalized environment with ``dim > 1`` and
    otherwise the same settings, acts on every axis alone (:class:`PerAxisPolicy`; it warns
    once, and says so in ``adaptation``).

    An ``env`` outside the training domain the file records is refused, naming every difference,
    unless ``allow_out_of_domain=True`` (docs: training.md, "The training domain").

    Raises ``FileNotFoundError`` naming ``policy`` when nothing is saved at ``path``, and
    :class:`~fxc_env.core.validation.ArgumentError` naming ``policy`` when the file is empty,
    damaged, not a PPO/SAC model, needs unpickling without ``trusted``, does not fit ``env``
    (naming the sizes, or the setting and both values), or ``env`` lies outside its training
    domain without ``allow_out_of_domain``.
    """
    boolean("allow_out_of_domain", allow_out_of_domain)
    path = pretrained_path(str(path)) if str(path) in SHIPPED and not Path(path).exists() else Path(path)
    policy = policy_format(path).read(path, trusted)
    if env is None:
        return policy
    # The one check after loading, whatever the format: sizes, training settings and domain, adapting the slots.
    config = config_of(env, "policy")
    if isinstance(policy, IntervalGainPolicy):  # reads any obs_slots; its own settings must match
        return policy.fit_to(config, allow_out_of_domain=allow_out_of_domain)  # type: ignore[return-value]
    trained = getattr(policy, "training_settings", None)
    per_axis, target, slots = _adaptation(policy, config)
    skip = ("dim",) if per_axis else ()
    if slots is not None and slots != target.slots and policy.action_size == (2 if per_axis else config.action_size):
        check_settings(trained, config, path, skip=(*skip, "obs_slots"))
        policy = adapt_slots(policy, config, target, slots, path, allow_out_of_domain=allow_out_of_domain)
    elif per_axis:
        check_settings(trained, config, path, skip=skip)
        check_domain(policy.training_domain, config, path, allow_out_of_domain)
    else:
        check_fit(policy, config, "policy", allow_out_of_domain=allow_out_of_domain)
        return policy
    if per_axis:
        policy = PerAxisPolicy(policy, config)
        warnings.warn(f"policy: {path} was {policy.adaptation} (PerAxisPolicy)", PolicyAdaptedWarning, stacklevel=2)
    return policy


def saved_format(path: str | Path) -> str:
    """The format of the saved policy at ``path``, as :func:`load_learned_policy` reads it, for messages:
    ``gain schedule`` (``.npz``), ``torch policy``, ``RLlib checkpoint`` (another directory) or ``SB3 model``."""
    return policy_format(path).name


@dataclass(frozen=True)
class PolicyFormat:
    """A format of saved policy, as :func:`load_learned_policy` reads it (one entry of :data:`POLICY_FORMATS`).

    Attributes:
        name: the format in messages (:func:`saved_format`).
        suffixes: the file suffixes it is recognised by, from the path alone (nothing is opened).
        member: a directory holding this file is this format too (a run directory), or None.
        any_directory: every other directory is this format.
        read: ``read(path, trusted)``, the policy saved at ``path``, read as data: no code from the file runs,
            except in a format that can only unpickle, which refuses without ``trusted=True`` and reads nothing.
        record: the function (dotted path) that checks the file's records, each number and its training domain,
            with :mod:`fxc_env.policies.records`, before anything is built.
    """

    name: str
    suffixes: tuple[str, ...]
    member: str | None
    any_directory: bool
    read: Callable[[Path, bool], Any]
    record: str

    def recognises(self, path: Path) -> bool:
        """Whether ``path`` is of this format, judged from the path (its suffix, or a directory's file names)."""
        if path.suffix in self.suffixes:
            return True
        return path.is_dir() and (self.any_directory or (self.member is not None and (path / self.member).is_file()))


_HERE = "fxc_env.policies"


def _read_torch_policy(path: Path, trusted: bool) -> Any:
    from fxc_env.policies.torch_policy import load_torch_policy  # torch only when a torch policy is read

    return load_torch_policy(path)


#: The formats :func:`load_learned_policy` reads, in the order a path is tried; a path none recognises is read as
#: the last (an SB3 ``.zip``, whose reader names what the file lacks). Adding a format is one entry here.
POLICY_FORMATS = (
    PolicyFormat(
        "gain schedule",
        (".npz",),
        None,
        False,
        lambda p, _: read_interval_gains(p),
        f"{_HERE}.interval_gains.IntervalGainPolicy",
    ),
    PolicyFormat("torch policy", (".pt",), "policy.pt", False, _read_torch_policy, f"{_HERE}.torch_policy.TorchPolicy"),
    PolicyFormat(
        "RLlib checkpoint", (), None, True, lambda p, t: RLlibPolicy(p, trusted=t), f"{_HERE}.learned.rllib_record"
    ),
    PolicyFormat(
        "SB3 model",
        (".zip",),
        None,
        False,
        lambda p, t: LearnedPolicy(p, trusted=t),
        f"{_HERE}.policy_files.read_sb3_zip",
    ),
)


def policy_format(path: str | Path) -> PolicyFormat:
    """The entry of :data:`POLICY_FORMATS` that reads ``path`` (the first that recognises it, else the last)."""
    path = Path(path)
    return next((f for f in POLICY_FORMATS if f.recognises(path)), POLICY_FORMATS[-1])


def _adaptation(policy: Any, config: Any) -> tuple[bool, Any, int | None]:
    """Whether ``policy`` acts per axis in ``config``, the layout it then reads and its trained slots there."""
    trained = getattr(policy, "training_settings", None)
    layout = config.layout
    axis = ObservationLayout(layout.slots, 1, limit_feature=layout.limit_feature)
    per_axis = (
        config.dim > 1
        and config.obs_mode == "normalized"
        and policy.action_size == 2
        and trained_slots(policy.obs_size, axis) is not None
        and (not trained or trained.get("dim", 1) == 1)
    )
    target = axis if per_axis else layout
    return per_axis, target, trained_slots(policy.obs_size, target)


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


class RLlibPolicy(Policy):
    """A trained RLlib module acting for every agent (parameter sharing), deterministically.

    Loads only the module (``learner_group/learner/rl_module/<module_id>`` of an algorithm
    checkpoint), on the CPU, without starting Ray; needs Ray RLlib installed. The action is
    the mode of the module's action distribution (the Gaussian's mean), clipped to the
    action space as during training. Where it was trained is read, as plain JSON, from the
    checkpoint's ``fxc_policy.json`` (:func:`~fxc_env.policies.saving.write_rllib_record`); for
    a checkpoint of an older run without it, from its run directory's ``config.json`` (the
    scenario and hyperparameter ``env`` it trained on); a checkpoint with neither records no
    training environment, and its settings and domain are not checked (as an SB3 ``.zip``
    without its record).

    Args:
        checkpoint: an RLlib algorithm checkpoint directory, or a run directory of
            ``fxc train --backend rllib`` (its newest checkpoint).
        env: an fxc_env environment or EnvConfig, checked against the module's sizes, its
            training settings and its training domain.
        module_id: the module to load.
        trusted: must be True: RLlib restores a module by unpickling its checkpoint
            (``class_and_ctor_args.pkl`` and friends), which runs any code a crafted
            checkpoint holds. Without it the checkpoint is refused and nothing in it is read.
        allow_out_of_domain: run in an ``env`` outside the training domain, with an
            :class:`~fxc_env.policies.domain.OutOfDomainWarning` naming every difference
            (refused by name otherwise; :func:`fxc_env.policies.domain.check_domain`).

    Attributes:
        training_settings: the settings of the environment it was trained on
            (:func:`fxc_env.policies.policy_files.training_settings`), or None when nothing records them.
        training_domain: where it was trained (:func:`fxc_env.policies.domain.training_domain`), or None.
    """

    def __init__(
        self,
        checkpoint: str | Path,
        env: Any = None,
        module_id: str = RLLIB_MODULE,
        *,
        trusted: bool = False,
        allow_out_of_domain: bool = False,
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
        self.training_settings, self.training_domain = rllib_record(found)
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
            check_fit(self, env, "RLlibPolicy", allow_out_of_domain=allow_out_of_domain)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for flat observations ``(..., obs_size)``."""
        import torch

        obs = np.asarray(obs, dtype=np.float32)
        lead = obs.shape[:-1]
        with torch.no_grad():
            out = self.module.forward_inference({"obs": torch.as_tensor(obs.reshape(-1, self.obs_size))})
            actions = self._distribution.from_logits(out["action_dist_inputs"]).to_deterministic().sample()
        actions = np.clip(actions.numpy().astype(np.float64), self._low, self._high)
        return actions.reshape((*lead, self.action_size))


def rllib_record(checkpoint: Path) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """``(training_settings, training_domain)`` of the RLlib checkpoint directory ``checkpoint``, read as plain JSON.

    From its ``fxc_policy.json`` (:func:`~fxc_env.policies.saving.write_rllib_record`); else, for an older run,
    from the run directory's ``config.json`` (the scenario and the hyperparameter file's ``env``, as
    ``fxc train --backend rllib`` builds the environment); else ``(None, None)``. Raises
    :class:`ArgumentError` naming ``policy`` and the file when ``fxc_policy.json`` is there but unreadable.
    """
    path = checkpoint / METADATA_MEMBER
    if path.is_file():
        try:
            record = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
            raise ArgumentError(f"policy: {path} is not readable JSON ({summary(exc)})") from exc
        if not isinstance(record, dict) or record.get("format") != RLLIB_RECORD_FORMAT:
            raise ArgumentError(f"policy: {path} is not a {RLLIB_RECORD_FORMAT!r} record")
        settings, domain = record.get("env"), checked_domain(record.get("domain"), path)
        return settings, domain or domain_from_settings(settings)
    run_config = checkpoint.parent.parent / "config.json"
    if checkpoint.parent.name != "checkpoints" or not run_config.is_file():
        return None, None
    try:
        started = json.loads(run_config.read_text())
        env = {k: v for k, v in started["hyperparams"]["env"].items() if k != "n_envs"}
        config = make_config(**{"scenario": started["args"]["scenario"], **env})
    except (OSError, UnicodeDecodeError, ValueError, RecursionError, KeyError, TypeError, AttributeError):
        return None, None  # a damaged config.json records nothing readable (ArgumentError is a ValueError)
    return training_settings(config), training_domain(config)
