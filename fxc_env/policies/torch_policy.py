"""Policies trained by ``fxc train --backend torchrl``, loaded for use: :func:`load_torch_policy`.

The policy file (``policy.pt`` in a run directory, or inside a checkpoint) is a ``torch.save``
of a plain dictionary that loads with ``weights_only=True``: ``format``
(:data:`POLICY_FORMAT`), ``obs_size``, ``action_size``, ``action_bound``, ``hidden`` (the
widths), ``activation``, ``actor`` (the state dict of the mean network, an ``nn.Sequential``
of ``Linear`` and activation layers), ``log_std``, ``env`` (``scenario`` and the environment
keywords it was trained on), ``domain`` (its training domain,
:func:`fxc_env.policies.domain.training_domain`; absent in older files, then derived from ``env``)
and ``timesteps``; ``arch`` (absent: ``mlp``) names the actor, ``gru``
(``gru_size``, ``clock_index``) or ``gnn`` (``embed_size``, ``rounds``) of
:mod:`fxc_env.policies.torch_memory`. The trainer lives in :mod:`fxc_env.training.backends.torch_ppo`;
this module is what evaluation needs.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fxc_env.config import make_config
from fxc_env.core.validation import FLOAT32_MAX, ArgumentError
from fxc_env.policies.domain import training_domain
from fxc_env.policies.fit import check_fit, check_width, settings_from_env_kwargs
from fxc_env.policies.networks import ACTIVATIONS, mlp  # noqa: F401  (their public path before networks.py)
from fxc_env.policies.protocol import Policy, call_policy
from fxc_env.policies.records import checked_domain, file_number, file_tensor
from fxc_env.policies.torch_memory import build_actor

#: The ``format`` of a policy record, and of a checkpoint (which holds one under ``"policy"``).
POLICY_FORMAT = "fxc_env.torch_ppo.policy/1"
CHECKPOINT_FORMAT = "fxc_env.torch_ppo.checkpoint/1"


class TorchPolicy(Policy):
    """A trained policy, deterministic: observations ``[..., obs_size]`` to actions ``[..., action_size]``.

    The action is the Gaussian's mean clipped to ``±action_bound`` (training clips its
    samples to the same bound). numpy in, numpy (float64) out; a torch tensor in, a tensor
    out on its device, in its floating dtype (float32 for other dtypes). ``env`` holds the
    scenario and environment keywords it was trained on; :attr:`training_settings` the
    settings they make (:func:`fxc_env.policies.policy_files.training_settings`), which
    :func:`fxc_env.policies.learned.load_learned_policy` checks against the environment.
    """

    def __init__(self, record: Mapping[str, Any], source: str | Path | None = None) -> None:
        self.source = source
        if record.get("format") != POLICY_FORMAT:
            raise ArgumentError(f"policy: expected a {POLICY_FORMAT!r} record, got format {record.get('format')!r}")
        label = source or "the policy record"
        self.obs_size, self.action_size, self.action_bound = checked_numbers(record, label)
        self.env: dict[str, Any] = dict(record.get("env", {}))
        self.timesteps = file_number(label, "timesteps", record.get("timesteps", 0), integral=True, minimum=0)
        #: ``mlp`` (absent in older files), ``gru`` or ``gnn`` (:mod:`fxc_env.policies.torch_memory`).
        self.arch = str(record.get("arch", "mlp"))
        actor = record["actor"]  # a non-mapping fails in load_state_dict below, as a damaged file
        for name, weight in actor.items() if isinstance(actor, Mapping) else ():  # checked before anything is built
            file_tensor(label, f"actor.{name}", weight)
        recorded = checked_domain(record.get("domain"), label)
        self.module = build_actor(record, self.obs_size, self.action_size)
        self.module.load_state_dict(record["actor"])
        self.module.eval().requires_grad_(False)
        #: The settings of the environment ``env`` describes (None when it records none or does not build).
        self.training_settings: dict[str, Any] | None = settings_from_env_kwargs(self.env) if self.env else None
        #: Where it was trained (:mod:`fxc_env.policies.domain`): the record's ``domain``, else the one ``env`` makes.
        self.training_domain: dict[str, Any] | None = recorded or self._domain_of_env()
        self._hidden: torch.Tensor | None = None  # gru: the memory of the episodes under way

    def _domain_of_env(self) -> dict[str, Any] | None:
        """The training domain ``env`` makes (a file that records none), or None when it records none or fails."""
        if not self.env:
            return None
        try:
            return training_domain(make_config(**self.env))
        except (ArgumentError, TypeError):
            return None

    @property
    def needs_team(self) -> bool:  # type: ignore[override]
        """A ``gru`` keeps a memory per agent: one agent's observation alone is refused (:mod:`fxc_env.policies.protocol`)."""
        return self.arch == "gru"

    def reset(self) -> None:
        """Forget the memory (``gru``); an episode's first observation (clock ``k/K = 0``) also resets it."""
        self._hidden = None

    def __call__(self, observations: Any, graph: tuple[Any, Any] | None = None) -> Any:
        """Actions for observations ``[..., obs_size]``.

        ``gru``: one call per sampling instant; the memory is carried from call to call for
        observations of the same leading shape and reset per episode (clock ``k/K = 0``), or
        when the shape changes, or by :meth:`reset`. ``gnn``: ``observations`` ``[..., N,
        obs_size]`` and ``graph``, the interval graph's ``(edge_index, edge_mask)`` ``[..., 2, E]``,
        ``[..., E]`` (:func:`fxc_env.policies.torch_memory.interval_graph`). The parallel env's
        ``{agent: observation}`` gives ``{agent: action}``, the agents acting as one batch; a ``gru``
        refuses one agent's observation alone (:mod:`fxc_env.policies.protocol`: its memory is per
        agent). Dict observations (``obs_format="dict"``) are read as their flat form.
        """
        return call_policy(self, observations, lambda obs: self.act(obs, graph), convert=False)

    def act(self, observations: Any, graph: tuple[Any, Any] | None = None) -> Any:
        """Actions ``[..., action_size]`` for flat observations ``[..., obs_size]`` (numpy or torch; see :meth:`__call__`)."""
        numpy_in = not isinstance(observations, torch.Tensor)
        x = torch.as_tensor(np.asarray(observations) if numpy_in else observations)
        if x.ndim < 1 or x.shape[-1] != self.obs_size:
            raise ArgumentError(f"observations: expected shape [..., {self.obs_size}], got {tuple(x.shape)}")
        if self.arch == "gnn" and graph is None:
            raise ArgumentError(
                "graph: a 'gnn' policy passes messages along the interval graph; call it with "
                "graph=(edge_index, edge_mask) (observations alone do not say who is whose neighbour)"
            )
        device = next(self.module.parameters()).device
        if x.device != device:
            self.module.to(x.device)
        with torch.no_grad():
            x32 = x.to(torch.float32)
            if self.arch == "gru":
                hidden = self._hidden
                if hidden is None or hidden.shape[:-1] != x32.shape[:-1] or hidden.device != x32.device:
                    hidden = self.module.initial_state(tuple(x32.shape[:-1]), x32.device)
                mean, self._hidden = self.module.step(x32, hidden)
            elif self.arch == "gnn":
                index, mask = (torch.as_tensor(np.asarray(g) if not isinstance(g, torch.Tensor) else g) for g in graph)
                mean = self.module(x32, index.to(x32.device), mask.to(x32.device) > 0)
            else:
                mean = self.module(x32)
            actions = mean.clamp(-self.action_bound, self.action_bound)
        if numpy_in:
            return actions.double().numpy()
        return actions.to(x.dtype) if x.is_floating_point() else actions


#: The integer entries of a policy record besides the sizes (those its ``arch`` uses): their smallest values, and
#: their largest as an offset from ``obs_size`` (an index into the observation), or None.
ARCH_INTEGERS = {
    "gru_size": (1, None),
    "clock_index": (0, -1),
    "rows_end": (0, 0),
    "embed_size": (1, None),
    "rounds": (1, None),
}


def checked_numbers(record: Mapping[str, Any], source: Any) -> tuple[int, int, float]:
    """``(obs_size, action_size, action_bound)`` of a policy record once every number in it is well formed.

    The sizes and the ``hidden`` widths integers >= 1, ``action_bound`` positive and finite in float32 (the actor
    clamps its float32 mean to ``±action_bound``), the :data:`ARCH_INTEGERS` in range, ``log_std`` finite of shape
    ``(action_size,)``; else an :class:`ArgumentError` naming ``policy``, ``source`` and the field
    (:func:`fxc_env.policies.records.file_number`). A missing key raises ``KeyError`` (the loader names it).
    """
    obs_size = file_number(source, "obs_size", record["obs_size"], integral=True, minimum=1)
    action_size = file_number(source, "action_size", record["action_size"], integral=True, minimum=1)
    bound = file_number(source, "action_bound", record["action_bound"], positive=True, maximum=FLOAT32_MAX)
    hidden = record["hidden"]
    if not isinstance(hidden, list | tuple):
        raise ArgumentError(f"policy: {source}: hidden: expected a list of layer widths, got {hidden!r}")
    for width in hidden:
        file_number(source, "hidden", width, integral=True, minimum=1)
    for key, (smallest, offset) in ARCH_INTEGERS.items():
        if key in record:
            largest = None if offset is None else obs_size + offset
            file_number(source, key, record[key], integral=True, minimum=smallest, maximum=largest)
    if "log_std" in record:
        file_tensor(source, "log_std", record["log_std"], (action_size,))
    return obs_size, action_size, bound


def load_torch_policy(path: str | Path, env: Any = None, *, allow_out_of_domain: bool = False) -> TorchPolicy:
    """The deterministic policy of ``path``: a run directory (its ``policy.pt``), a ``policy.pt`` or a checkpoint.

    Returns a :class:`TorchPolicy`: ``policy(obs)`` maps ``[..., obs_size]`` (numpy or torch)
    to actions ``[..., action_size]``, the clipped mean of the trained Gaussian. With ``env``
    (an fxc_env environment or EnvConfig) the policy must fit it: its sizes and the settings
    its ``env`` record makes (:func:`fxc_env.policies.learned.check_fit`, an
    :class:`ArgumentError` naming the setting and both values otherwise), and ``env`` must lie
    inside its training domain unless ``allow_out_of_domain`` (:mod:`fxc_env.policies.domain`).
    """
    path = Path(path)
    if path.is_dir():
        path = path / "policy.pt"
    if not path.is_file():
        raise ArgumentError(f"policy: no torch policy file at {str(path)!r}")
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a foreign or damaged file
        raise ArgumentError(f"policy: {str(path)!r} is not a torch policy file ({exc})") from exc
    if isinstance(record, dict) and record.get("format") == CHECKPOINT_FORMAT:
        if "policy" not in record:
            raise ArgumentError(f"policy: the checkpoint {str(path)!r} lacks the key 'policy' (its policy record)")
        record = record["policy"]
    if not isinstance(record, dict):
        raise ArgumentError(f"policy: {str(path)!r} is not a torch policy file")
    try:
        policy = TorchPolicy(record, source=path)
    except ArgumentError:
        raise
    except KeyError as exc:  # a record of the right format with a key missing
        raise ArgumentError(
            f"policy: {str(path)!r} lacks the key {exc.args[0]!r} of a {POLICY_FORMAT!r} record (damaged, or "
            "written by another version)"
        ) from exc
    except (RuntimeError, TypeError, ValueError) as exc:  # missing, extra or misshapen weights; a wrong value
        raise ArgumentError(f"policy: {str(path)!r} does not load as a torch policy: {one_line(exc)}") from exc
    if env is not None:
        check_width(policy, env, path)  # a fixed-width network: another obs_slots is refused by name
        check_fit(policy, env, "policy", allow_out_of_domain=allow_out_of_domain)
    return policy


def one_line(error: BaseException, limit: int = 400) -> str:
    """``error``'s message on one line (torch's ``load_state_dict`` lists missing and unexpected keys and
    shapes on several), at most ``limit`` characters."""
    text = " ".join(str(error).split()) or type(error).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def is_torch_policy(path: str | Path) -> bool:
    """Whether ``path`` is a torch policy file (``.pt``) or a run directory holding ``policy.pt``."""
    path = Path(path)
    return path.suffix == ".pt" or (path.is_dir() and (path / "policy.pt").is_file())
