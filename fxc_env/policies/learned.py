"""A saved policy (stable-baselines3 model or RLlib checkpoint) as a policy on the local observation.

:class:`LearnedPolicy` (SB3) and :class:`RLlibPolicy` have the calling convention of
:class:`fxc_env.ReferencePolicy`: observations ``(..., obs_size)`` in, actions
``(..., 2 dim)`` out, deterministic. :func:`load_learned_policy` is the one place that decides
how a saved policy loads.

**Loading runs no code from the file.** An SB3 ``.zip`` is read by
:func:`fxc_env.policies.policy_files.read_sb3_zip` (plain JSON and ``weights_only`` tensors;
nothing is unpickled), a torch policy loads with ``weights_only=True``. Formats that can only be
unpickled (an RLlib checkpoint, VecNormalize's ``.pkl``, SB3's own loader for networks the
safe reader does not rebuild) need ``trusted=True``: unpickling a file runs whatever code its
author put in it (README, "Training learned policies").

**A policy meets the settings it was trained for.** A file that records its training
environment (SB3 ``.zip`` files saved by ``fxc train`` or
:func:`~fxc_env.policies.policy_files.save_model`, torch policies) is refused in an environment
whose action or observation mode, input-limit feature, agent model, dimension or
observation slots differ (:data:`fxc_env.policies.policy_files.CHECKED_SETTINGS`), with an
error naming the setting and both values, and in one outside its **training domain** (graphs,
N, switching, schedule, K, limits, noise: :mod:`fxc_env.policies.domain`), naming every
difference, unless ``allow_out_of_domain=True`` (then an
:class:`~fxc_env.policies.domain.OutOfDomainWarning` names them). :func:`load_learned_policy`
adapts two settings:

* **any obs_slots and N** (:class:`SlotAdaptedPolicy`): the observation is rebuilt in the
  trained layout. Fewer rows than trained with are padded exactly as an environment built
  with the trained ``obs_slots`` pads them (same actions, bit for bit); more rows are read by
  the gain-scheduled networks (:data:`ROW_WISE_POLICIES`), grouped and rescaled to the
  in-degree as eq. (11) scales its gains (a :class:`PolicyAdaptedWarning`), and refused for
  a fixed-width network (an MLP), naming its architecture, its width and the environment's.
* **dim**: a model trained in one dimension acts per axis in a ``dim > 1`` environment
  (:class:`PerAxisPolicy`, which says so in :attr:`PerAxisPolicy.adaptation`).

:class:`LearnedPolicy` itself takes only observations of the model's size.
"""

from __future__ import annotations

import json
import pickle
import re
import warnings
import zipfile
import zlib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.config.layout import CLOCK_SIZE
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import check_domain, checked_allow, domain_from_settings, training_domain
from fxc_env.policies.policy_files import (
    TRUST_HINT,
    check_settings,
    checked_zip_path,
    describe_differences,
    read_metadata,
    read_sb3_zip,
    setting_differences,
    training_settings,
)

#: The policies that ship with the package, by name (README, "Training learned policies"):
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
    "rings_scratch": "rings_scratch.npz",  # a gain schedule learned from scratch (fxc_env.training.rings_scratch)
    "agnostic": "agnostic.npz",  # one gain schedule for any graph, not told the graph (fxc_env.training.agnostic)
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
        self.training_settings = _recorded_settings(self.model)
        self._stats = getattr(self.model, "normalization", None)
        self.training_domain = _recorded_domain(self.model, self.training_settings)
        if self.source is not None and trusted:  # SB3's loader: the plain record still says how it was trained
            record = read_metadata(self.source) or {}
            self.training_settings = self.training_settings or record.get("env")
            self.training_domain = record.get("domain") or domain_from_settings(self.training_settings)
            self._stats = self._stats or record.get("normalization")
        if self._stats is not None:
            self._stats = normalization_stats(self._stats, self.obs_size, self.source)
        if vecnormalize is not None:
            self._stats = read_normalization(vecnormalize, self.obs_size, trusted=trusted)
        if env is not None:
            check_fit(self, env, "LearnedPolicy", allow_out_of_domain=allow_out_of_domain)

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for observations ``(..., obs_size)``."""
        obs = np.asarray(observation, dtype=np.float64)
        lead = obs.shape[:-1]
        flat = obs.reshape(-1, self.obs_size)
        if self._stats is not None:
            s = self._stats
            flat = np.clip((flat - s["mean"]) / np.sqrt(s["var"] + s["epsilon"]), -s["clip_obs"], s["clip_obs"])
        actions, _ = self.model.predict(flat, deterministic=True)
        return np.asarray(actions, dtype=np.float64).reshape((*lead, self.action_size))


def _recorded_settings(model: Any) -> dict[str, Any] | None:
    """The training settings a model records: a SavedModel's ``fxc_policy.json``, or an in-memory model's env."""
    if hasattr(model, "training"):
        return model.training
    get_env = getattr(model, "get_env", None)
    vec = get_env() if callable(get_env) else None
    while vec is not None and hasattr(vec, "venv"):
        vec = vec.venv
    if vec is None:
        return None
    try:
        return training_settings(vec)
    except (ArgumentError, AttributeError):
        return None


def _recorded_domain(model: Any, settings: Any) -> dict[str, Any] | None:
    """The training domain a model records (a SavedModel's), an in-memory model's env's, or the part its settings give."""
    recorded = getattr(model, "domain", None)
    if recorded:
        return recorded
    if not hasattr(model, "training"):  # SB3's own model in memory: its training environment, if it has one
        get_env = getattr(model, "get_env", None)
        vec = get_env() if callable(get_env) else None
        while vec is not None and hasattr(vec, "venv"):
            vec = vec.venv
        if vec is not None:
            try:
                return training_domain(vec)
            except (ArgumentError, AttributeError):
                pass
    return domain_from_settings(settings)


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
        raise ArgumentError(f"vecnormalize: cannot read statistics from {path} ({_summary(exc)})") from exc
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
        raise ArgumentError(f"vecnormalize: cannot read statistics from {source} ({_summary(exc)})") from exc
    if stats["mean"].shape != (obs_size,) or stats["var"].shape != (obs_size,):
        raise ArgumentError(
            f"vecnormalize: {source} holds statistics of shape {stats['mean'].shape}; the model takes ({obs_size},)"
        )
    return stats


def check_sizes(env: Any, obs_size: int, action_size: int, who: str, note: str = "") -> None:
    """Refuse an environment whose observation or action size differs from the model's."""
    from fxc_env.config import config_of

    config = config_of(env, who)
    if (config.layout.size, config.action_size) != (obs_size, action_size):
        reason = f"; {note}" if note else " (train with the same obs_slots, dim and modes, or pass obs_slots)"
        raise ArgumentError(
            f"policy: the model takes observations of size {obs_size} and gives actions of size "
            f"{action_size}; this environment has {config.layout.size} and {config.action_size}{reason}"
        )


def check_fit(
    policy: Any, env: Any, who: str = "policy", skip: tuple[str, ...] = (), *, allow_out_of_domain: bool = False
) -> None:
    """Refuse an environment that ``policy`` does not fit: its sizes, its recorded training settings, its domain.

    The size error names the sizes (and, where the policy records them, the settings behind
    them); the settings error names each setting that differs and both values
    (:func:`fxc_env.policies.policy_files.check_settings`); an environment outside the
    policy's ``training_domain`` is refused naming every difference unless
    ``allow_out_of_domain`` (then a warning names them; :func:`fxc_env.policies.domain.check_domain`).
    """
    from fxc_env.config import config_of

    config = config_of(env, who)
    trained = getattr(policy, "training_settings", None)
    source = getattr(policy, "source", None) or "this path"
    differences = setting_differences(trained, config, skip)
    check_sizes(config, policy.obs_size, policy.action_size, who, describe_differences(differences))
    check_settings(trained, config, source, skip)
    check_domain(getattr(policy, "training_domain", None), config, source, allow_out_of_domain, stacklevel=4)


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
            raise ArgumentError(f"policy: cannot load the RLlib module in {module_dir} ({_summary(exc)})") from exc
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


#: SB3 policy classes whose action is linear in each neighbour row (:mod:`fxc_env.policies.gain_network`):
#: they act on any number of rows (:class:`SlotAdaptedPolicy`). Every other network reads a fixed width.
ROW_WISE_POLICIES = ("GainScheduledPolicy", "GatedGainPolicy")


def trained_slots(obs_size: int, layout: Any) -> int | None:
    """The neighbour slots of an observation of ``obs_size`` in ``layout``'s form (its dim, model, limit entry).

    ``(obs_size - 3 - limit) / (row_size + 1)`` when that is a whole number of at least 1, else None
    (the observation is not that layout with another number of slots).
    """
    slots, remainder = divmod(obs_size - CLOCK_SIZE - int(layout.limit_feature), layout.row_size + 1)
    return slots if remainder == 0 and slots >= 1 else None


def largest_in_degree(config: Any) -> int:
    """The largest in-degree an agent of ``config`` can have (over its topology set or family's draws)."""
    if config.family is not None:
        return int(config.family.max_in_degree(config.n_agents))
    return int(config.topology.max_in_degree)


def architecture_of(policy: Any) -> tuple[str, bool]:
    """``(name, reads any number of rows)`` of a loaded policy's network, for messages and :class:`SlotAdaptedPolicy`."""
    model = getattr(policy, "model", None)
    if model is not None:  # LearnedPolicy: a SavedModel, or SB3's own model (trusted)
        cls = getattr(model, "policy_class", None)  # a SavedModel's is a name, SB3's own a class
        if not isinstance(cls, str):
            cls = type(getattr(model, "policy", model)).__name__
        if cls in ROW_WISE_POLICIES:
            return f"the gain-scheduled network {cls}", True
        arch = getattr(model, "metadata", None) or {}
        widths = arch.get("net_arch") if isinstance(arch, dict) else None
        return f"an MLP ({cls}{'' if widths is None else f', net_arch {widths}'})", False
    arch = getattr(policy, "arch", None)
    if isinstance(policy, RLlibPolicy):
        return "an RLlib module (fxc train --backend rllib)", False
    if type(policy).__name__ == "TorchPolicy":  # fxc train --backend torch: mlp, gru or gnn actors
        labels = {"mlp": "MLP", "gru": "GRU actor", "gnn": "message-passing actor"}
        return f"a torch {labels.get(arch or 'mlp', repr(arch))} (fxc train --backend torch)", False
    return f"a fixed-width network ({type(policy).__name__})", False


def check_width(policy: Any, env: Any, source: Any) -> None:
    """Refuse, naming the architecture, its width and the environment's, an environment whose
    observation differs from a fixed-width ``policy``'s only in its neighbour slots.

    For loaders that return the policy itself (:func:`fxc_env.policies.torch_policy.load_torch_policy`);
    :func:`load_learned_policy` instead adapts what can be adapted exactly (:func:`adapt_slots`).
    """
    from fxc_env.config import config_of

    config = config_of(env, "policy")
    layout = config.layout
    slots = trained_slots(policy.obs_size, layout)
    if slots is None or slots == layout.slots:
        return
    check_settings(getattr(policy, "training_settings", None), config, source, skip=("obs_slots",))
    name, _ = architecture_of(policy)
    raise ArgumentError(
        f"policy: the model at {source} is {name}, which reads a fixed {slots} neighbour rows (observations of "
        f"size {policy.obs_size}); this environment has {layout.slots} (obs_slots: trained with {slots}, this "
        f"environment has {layout.slots}, observations of size {layout.size}). "
        "fxc_env.policies.learned.load_learned_policy(path, env) pads fewer rows exactly"
    )


class SlotAdaptedPolicy:
    """A policy trained on ``W`` neighbour slots acting on an environment's observations of ``S`` slots.

    The observation (README, "Observation"; :class:`fxc_env.config.layout.ObservationLayout`) is
    rebuilt in the trained layout, row by row, and the policy (with any VecNormalize statistics
    it records, which are per slot of the trained layout) acts on that:

    * masked rows are ignored: set to zero (as the environment writes them anyway).
    * an agent whose real rows all sit in the first ``W`` slots (always when ``S <= W``, and
      when its in-degree is at most ``W``) gets the first ``W`` slots as they are, padded with
      zero rows and mask 0 up to ``W``: exactly the observation an environment built with
      ``obs_slots=W`` writes (rows are zero padded at the end, masked rows are zero), so the
      action is the same bit for bit. This is the only case a fixed-width network (an MLP) meets:
      :func:`load_learned_policy` refuses it for an environment whose in-degree exceeds ``W``.
    * an agent with more than ``W`` real rows (gain-scheduled networks only, which are linear in
      each row: ``alpha_i = sum_j G_j row_ij``) gets its ``d`` rows summed into ``W`` groups
      of consecutive rows, each sum times ``(W + 1) / (d + 1)``, with all ``W`` mask entries 1:
      the network acts as at in-degree ``W`` and its gains are rescaled from ``1/(W + 1)`` to
      ``1/(d + 1)``, as the paper's controller (eq. 11, gains ``[[1, 1], [0, 1]] / (d_i + 1)``)
      scales with the in-degree; for that controller the result is exact. It is an
      extrapolation beyond the in-degrees the network was trained on (the loader warns, with a
      :class:`PolicyAdaptedWarning`); VecNormalize statistics then normalise each group sum with
      the statistics of the trained slot it is written into (no slot's statistics are borrowed
      for another).
    * an agent with at most ``W`` real rows of which some sit beyond slot ``W`` (link dropout
      masks rows where they are) gets its real rows moved, in order, into the first slots.

    Args:
        policy: a policy on flat observations of the trained layout (``(..., trained.size)``).
        layout: the environment's observation layout (one axis of it for :class:`PerAxisPolicy`).
        slots: ``W``, the policy's trained neighbour slots.
        reads_any_rows: True for the gain-scheduled networks; False refuses (``observations``) an
            observation with a real row beyond slot ``W``.

    Attributes:
        obs_size, action_size: the environment's observation size and the policy's action size.
        adaptation: what was adapted, as text (``"trained with 4 neighbour slots, acting on 1"``).
    """

    def __init__(self, policy: Any, layout: Any, slots: int, reads_any_rows: bool) -> None:
        from fxc_env.config.layout import ObservationLayout

        self.policy = policy
        self.layout = layout
        self.trained = ObservationLayout(slots, layout.dim, layout.limit_feature, layout.n_states)
        self.reads_any_rows = reads_any_rows
        self.obs_size = layout.size
        self.action_size = policy.action_size
        self.source = getattr(policy, "source", None)
        self.training_settings = getattr(policy, "training_settings", None)
        self.training_domain = getattr(policy, "training_domain", None)
        self.adaptation = f"trained with {slots} neighbour slots, acting on {layout.slots}"

    def trained_observation(self, observation: Any) -> np.ndarray:
        """The observation ``(..., obs_size)`` (or a dict one) rebuilt in the trained layout ``(..., trained.size)``."""
        obs = self.layout.flat(observation)
        if obs.shape[-1:] != (self.obs_size,):
            raise ArgumentError(f"observations: expected shape (..., {self.obs_size}), got {obs.shape}")
        lead, width, have = obs.shape[:-1], self.trained.slots, self.layout.slots
        row = self.layout.row_size
        mask = obs[..., self.layout.rows_end : self.layout.mask_end]
        # Masked rows are ignored: zero, as the environment writes them (padding, dropped links).
        rows = np.where(mask[..., None] != 0, obs[..., : self.layout.rows_end].reshape((*lead, have, row)), 0.0)
        out = np.zeros((*lead, self.trained.size))
        keep = min(width, have)
        out[..., : keep * row] = rows[..., :keep, :].reshape((*lead, keep * row))
        out[..., self.trained.rows_end : self.trained.rows_end + keep] = mask[..., :keep]
        out[..., self.trained.mask_end :] = obs[..., self.layout.mask_end :]
        if have <= width:
            return out
        beyond = np.any(mask[..., width:] != 0, axis=-1)  # agents with a real row past the trained slots
        if not np.any(beyond):
            return out
        if not self.reads_any_rows:
            raise ArgumentError(
                f"observations: an agent has a real neighbour row beyond the {width} rows this fixed-width "
                "network reads (its in-degree exceeds the trained obs_slots)"
            )
        real = mask[beyond] != 0  # (M, S)
        degree = real.sum(axis=-1, keepdims=True)  # (M, 1)
        rank = np.cumsum(real, axis=-1) - 1
        grouped = degree > width
        target = np.where(grouped, (rank * width) // np.maximum(degree, 1), rank)  # the trained slot of each row
        factor = np.where(grouped, (width + 1) / (degree + 1), 1.0)  # (M, 1)
        assign = (target[..., None, :] == np.arange(width)[:, None]) & real[..., None, :]  # (M, W, S)
        sums = (assign * factor[..., None]) @ rows[beyond]  # (M, W, row)
        picked = out[beyond]
        picked[..., : self.trained.rows_end] = sums.reshape(len(sums), -1)
        picked[..., self.trained.rows_end : self.trained.mask_end] = np.arange(width) < np.minimum(degree, width)
        out[beyond] = picked
        return out

    def __call__(self, observation: Any) -> Any:
        """Actions ``(..., action_size)`` for observations ``(..., obs_size)`` of the environment's layout.

        A mapping ``{agent: observation}`` (a PettingZoo env's observations) gives ``{agent: action}``,
        the agents acting as one batch.
        """
        agents = agent_observations(observation)
        if agents is not None:
            return dict(zip(agents, self(np.stack([self.layout.flat(agents[a]) for a in agents])), strict=True))
        return np.asarray(self.policy(self.trained_observation(observation)), dtype=np.float64)

    def reset(self) -> None:
        """The wrapped policy's ``reset`` (a torch GRU actor's memory), where it has one."""
        reset = getattr(self.policy, "reset", None)
        if callable(reset):
            reset()


class PerAxisPolicy:
    """A policy trained in one dimension acting on each axis of a ``dim``-dimensional environment.

    The paper's controller (eq. 11) acts on every axis alone, and so can a learned policy:
    for axis c the agent's normalized rows are rescaled by their own largest entry
    ``sigma_c`` (so the axis looks as it would alone, with local scale ``sigma_c s_i``), the
    one-dimensional policy acts, and its action, in units of ``sigma_c s_i``, is multiplied by
    ``sigma_c`` back into the environment's units of ``s_i`` (plan and accel actions are
    linear in the scale). The input-limit feature is recomputed for the axis's scale. Only
    for ``obs_mode="normalized"`` (raw observations carry no scale to split).

    Attributes:
        adaptation: what was adapted, as text (``"trained in dim 1, acting per axis in dim 2"``).
        obs_size, action_size: the environment's (``(2 dim + 1) slots + 3 [+ 1]`` and ``2 dim``).
    """

    def __init__(self, policy: Any, config: Any) -> None:
        from fxc_env.config.layout import ObservationLayout

        self.policy = policy
        self.config = config
        self.layout = config.layout
        self.axis_layout = ObservationLayout(self.layout.slots, 1, limit_feature=self.layout.limit_feature)
        self.obs_size = self.layout.size
        self.action_size = config.action_size
        self.source = getattr(policy, "source", None)
        self.training_settings = getattr(policy, "training_settings", None)
        self.training_domain = getattr(policy, "training_domain", None)
        self.adaptation = f"trained in dim 1, acting per axis in dim {config.dim}"

    def __call__(self, observation: Any) -> Any:
        """Actions ``(..., 2 dim)`` for observations ``(..., obs_size)`` (flat or dict), or ``{agent: action}``
        for ``{agent: observation}``.

        A policy with a memory (a torch ``gru``) keeps one per agent and axis: it is refused one
        agent's observation alone (called agent by agent, every agent would run through one memory).
        """
        agents = agent_observations(observation)
        if agents is not None:
            return dict(zip(agents, self(np.stack([self.layout.flat(agents[a]) for a in agents])), strict=True))
        obs = self.layout.flat(observation)
        lead, dim = obs.shape[:-1], self.config.dim
        if not lead and has_memory(self.policy):
            raise ArgumentError(
                f"observations: this policy keeps a memory per agent and axis ({self.adaptation}); pass every "
                f"agent's observations at once, [N, {self.obs_size}] or a dict agent -> observation, not one "
                f"agent's ({self.obs_size},)"
            )
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

    **The training domain.** A policy file records where it was trained (graphs, N, switching,
    schedule, K, T_s, limits, noise: :mod:`fxc_env.policies.domain`). An ``env`` outside it is
    refused, naming every difference, unless ``allow_out_of_domain=True`` (``fxc evaluate`` and
    ``fxc benchmark``: ``--allow-out-of-domain``); then an
    :class:`~fxc_env.policies.domain.OutOfDomainWarning` names every difference.

    Raises ``FileNotFoundError`` naming ``policy`` when nothing is saved at ``path``, and
    :class:`~fxc_env.core.validation.ArgumentError` naming ``policy`` when the file is empty,
    damaged, not a PPO/SAC model, needs unpickling without ``trusted``, does not fit ``env``
    (naming the sizes, or the setting and both values), or ``env`` lies outside its training
    domain without ``allow_out_of_domain``.
    """
    checked_allow(allow_out_of_domain)
    path = pretrained_path(str(path)) if str(path) in SHIPPED and not Path(path).exists() else Path(path)
    from fxc_env.policies.torch_policy import is_torch_policy, load_torch_policy

    if path.suffix == ".npz":
        from fxc_env.policies.interval_gains import load_interval_gains

        return load_interval_gains(path, env, allow_out_of_domain=allow_out_of_domain)  # type: ignore[return-value]
    if is_torch_policy(path):
        policy: Any = load_torch_policy(path)
    elif path.is_dir():
        policy = RLlibPolicy(path, trusted=trusted)
    else:
        policy = LearnedPolicy(path, trusted=trusted)
    if env is None:
        return policy
    from fxc_env.config import config_of
    from fxc_env.config.layout import ObservationLayout

    config = config_of(env, "policy")
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
    slots = trained_slots(policy.obs_size, target)
    skip = ("dim",) if per_axis else ()
    if slots is not None and slots != target.slots and policy.action_size == (2 if per_axis else config.action_size):
        check_settings(trained, config, path, skip=(*skip, "obs_slots"))
        policy = adapt_slots(policy, config, target, slots, path, allow_out_of_domain=allow_out_of_domain)
        if per_axis:
            policy = PerAxisPolicy(policy, config)
    elif per_axis:
        check_settings(trained, config, path, skip=skip)
        check_domain(policy.training_domain, config, path, allow_out_of_domain)
        policy = PerAxisPolicy(policy, config)
    else:
        check_fit(policy, config, "policy", allow_out_of_domain=allow_out_of_domain)
        return policy
    if per_axis:
        warnings.warn(f"policy: {path} was {policy.adaptation} (PerAxisPolicy)", PolicyAdaptedWarning, stacklevel=2)
    return policy


def adapt_slots(
    policy: Any, config: Any, layout: Any, slots: int, source: Any, *, allow_out_of_domain: bool | None = None
) -> SlotAdaptedPolicy:
    """``policy`` (trained on ``slots`` neighbour slots) on observations of ``layout``: :class:`SlotAdaptedPolicy`.

    A fixed-width network (an MLP) is refused, naming its architecture, its width and the
    environment's, when an agent of ``config`` can have more in-neighbours than it reads; with
    at most that many it is exact (zero rows with mask 0 pad the observation, as an
    environment built with ``obs_slots=slots`` pads it). A gain-scheduled network reads any
    number of rows; beyond ``slots`` it acts by its per-row structure (:class:`SlotAdaptedPolicy`)
    and warns (:class:`PolicyAdaptedWarning`) that this extrapolates past the trained in-degrees.
    With ``allow_out_of_domain`` given, the policy's training domain is checked
    (:func:`fxc_env.policies.domain.check_domain`) once the width fits, before any warning.
    """
    name, reads_any_rows = architecture_of(policy)
    degree = largest_in_degree(config)
    if getattr(policy, "arch", None) == "gnn":  # its graph argument holds the environment's slots too
        raise ArgumentError(
            f"policy: the model at {source} is {name}, which reads {slots} neighbour slots of the observation and "
            f"of the graph it passes messages on; this environment has {layout.slots} (obs_slots: trained with "
            f"{slots}, this environment has {layout.slots}): build it with obs_slots={slots}"
        )
    if degree > slots and not reads_any_rows:
        raise ArgumentError(
            f"policy: the model at {source} is {name}, which reads a fixed {slots} neighbour rows (observations "
            f"of size {policy.obs_size}); this environment's agents have up to {degree} in-neighbours "
            f"(obs_slots: trained with {slots}, this environment has {layout.slots}). Fewer rows than {slots} are "
            "padded exactly, more cannot be read by this architecture: use a gain-scheduled policy "
            "(generalist, saturated) or one trained with enough obs_slots"
        )
    if allow_out_of_domain is not None:
        check_domain(getattr(policy, "training_domain", None), config, source, allow_out_of_domain, stacklevel=4)
    adapted = SlotAdaptedPolicy(policy, layout, slots, reads_any_rows)
    if degree > slots:
        warnings.warn(
            f"policy: {source} was {adapted.adaptation}: agents with more than {slots} in-neighbours (up to "
            f"{degree} here) act through {name}'s per-row gains, rescaled to their in-degree as eq. (11) "
            "scales (SlotAdaptedPolicy), beyond the in-degrees it was trained on",
            PolicyAdaptedWarning,
            stacklevel=3,
        )
    return adapted


def agent_observations(observation: Any) -> dict[Any, Any] | None:
    """``observation`` when it maps agents to observations (a PettingZoo env's), else None.

    A dict observation of one agent (``obs_format="dict"``: ``neighbours``, ``mask``, ``clock``
    [, ``input_limit``]) is not one: it is the agent's observation.
    """
    if isinstance(observation, Mapping) and "neighbours" not in observation:
        return dict(observation)
    return None


def has_memory(policy: Any) -> bool:
    """Whether ``policy`` (or the policy it wraps) carries a memory from call to call (a torch ``gru``)."""
    while policy is not None:
        if getattr(policy, "arch", None) == "gru":
            return True
        policy = getattr(policy, "policy", None)
    return False


class PolicyAdaptedWarning(UserWarning):
    """A saved policy was adapted to an environment it was not trained in (see :func:`load_learned_policy`)."""
