"""Whether a saved policy fits an environment: its sizes, the settings it was trained for, its width.

:func:`check_fit` refuses an environment whose observation or action size, or whose recorded
training settings (:data:`CHECKED_SETTINGS`: action and observation modes, the input-limit
feature, the agent model, dim, obs_slots), differ from the policy's, naming the setting and both
values, and one outside its training domain (:mod:`fxc_env.policies.domain`). Every reader
(:mod:`fxc_env.policies.learned`, :mod:`~fxc_env.policies.torch_policy`,
:mod:`~fxc_env.policies.interval_gains`) calls these.

A policy that does not fit may still act where it can do so exactly or by its structure: on another
number of neighbour slots (:class:`SlotAdaptedPolicy`, :func:`adapt_slots`) or per axis in ``dim > 1``
(:class:`PerAxisPolicy`); :func:`fxc_env.policies.learned.load_learned_policy` chooses.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from fxc_env.config import config_of, make_config
from fxc_env.config.layout import CLOCK_SIZE, ObservationLayout
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import check_domain
from fxc_env.policies.protocol import Policy, reset_policy

#: The settings of the training environment a loaded policy must meet (docs: training.md, "Training learned
#: policies"): the meaning of its inputs and outputs (action and observation modes, whether the
#: observation carries the input-limit (``u_max``) feature, the agent model), the dimension and the
#: observation slots (:func:`fxc_env.policies.learned.load_learned_policy` adapts the last two where
#: it can). Where the policy was trained (graphs, N, K, schedule, ...) is its training domain,
#: checked by :func:`fxc_env.policies.domain.check_domain`.
CHECKED_SETTINGS = ("action_mode", "obs_mode", "limit_feature", "agent_model", "dim", "obs_slots")


#: How a setting is named in refusals.
SETTING_LABELS = {"limit_feature": "the u_max feature (limit_feature)"}


#: The keyword of :func:`fxc_env.make_config` that sets each checked setting, for the hint.
SETTING_KEYWORDS = {
    "schedule": "schedule",
    "action_mode": "action_mode",
    "obs_mode": "obs_mode",
    "limit_feature": "u_max",
    "agent_model": "agent_model",
    "dim": "dim",
    "obs_slots": "obs_slots",
}


def training_settings(config: Any) -> dict[str, Any]:
    """The settings of an environment that a policy trained on it depends on, as plain JSON values.

    ``schedule`` (its name: ``paper``, ``uniform`` or ``custom``), ``action_mode``, ``obs_mode``,
    ``limit_feature`` (the observation's input-limit entry), ``agent_model`` (and ``model_A``,
    ``model_B`` for a model other than the double integrator), ``dim``, ``obs_slots``,
    ``obs_size``, ``action_size``, ``action_bound``; and, for the record, ``scenario``,
    ``n_agents``, ``n_intervals``, ``settling_time`` (s) and ``u_max`` (m/s^2, the set drawn from).
    """
    c = config_of(config, "env")
    settings: dict[str, Any] = {
        "scenario": c.scenario,
        "schedule": c.schedule.name,
        "action_mode": c.action_mode,
        "obs_mode": c.obs_mode,
        "limit_feature": bool(c.layout.limit_feature),
        "agent_model": c.agent_model,
        "dim": int(c.dim),
        "obs_slots": int(c.layout.slots),
        "obs_size": int(c.layout.size),
        "action_size": int(c.action_size),
        "action_bound": float(c.action_bound),
        "n_agents": int(c.n_agents),
        "n_intervals": int(c.n_intervals),
        "settling_time": float(c.settling_time),
        "u_max": None if c.u_max_choices is None else [float(u) for u in c.u_max_choices],
    }
    if c.model is not None:
        settings["model_A"] = np.asarray(c.model.A, dtype=float).tolist()
        settings["model_B"] = np.asarray(c.model.B, dtype=float).tolist()
    return settings


def settings_from_env_kwargs(env: Mapping[str, Any]) -> dict[str, Any] | None:
    """:func:`training_settings` of ``make_config(**env)`` (a torch policy's ``env`` record); None if it fails."""
    try:
        return training_settings(make_config(**dict(env)))
    except (ArgumentError, TypeError):
        return None


def setting_differences(
    trained: Mapping[str, Any] | None, config: Any, skip: tuple[str, ...] = ()
) -> list[tuple[str, Any, Any]]:
    """``(setting, trained value, this environment's value)`` for each checked setting that differs."""
    if not trained:
        return []
    here = training_settings(config)
    found = []
    for key in CHECKED_SETTINGS:
        if key in skip or key not in trained:
            continue
        if trained[key] != here[key]:
            found.append((key, trained[key], here[key]))
        elif key == "agent_model" and "model_A" in trained:
            for matrix in ("model_A", "model_B"):
                if not np.array_equal(np.asarray(trained[matrix]), np.asarray(here.get(matrix))):
                    found.append((matrix, trained[matrix], here.get(matrix)))
    return found


def describe_differences(differences: list[tuple[str, Any, Any]]) -> str:
    """``"schedule: trained with 'uniform', this environment has 'paper'; ..."``."""
    return "; ".join(
        f"{SETTING_LABELS.get(key, key)}: trained with {trained!r}, this environment has {here!r}"
        for key, trained, here in differences
    )


def check_settings(trained: Mapping[str, Any] | None, config: Any, source: Any, skip: tuple[str, ...] = ()) -> None:
    """Refuse (:class:`ArgumentError` naming ``policy``, the setting and both values) an environment
    whose checked settings (:data:`CHECKED_SETTINGS`) differ from those ``trained`` records.

    ``trained`` None or empty (a file that records no training environment) checks nothing.
    """
    differences = setting_differences(trained, config, skip)
    if differences:
        keywords = sorted({SETTING_KEYWORDS.get(key, "agent_model") for key, _, _ in differences})
        raise ArgumentError(
            f"policy: the model at {source} was trained for other settings: {describe_differences(differences)} "
            f"(make the environment match: {', '.join(keywords)}; or use a policy trained for these settings)"
        )


def check_sizes(env: Any, obs_size: int, action_size: int, who: str, note: str = "") -> None:
    """Refuse an environment whose observation or action size differs from the model's."""
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
    config = config_of(env, who)
    trained = getattr(policy, "training_settings", None)
    source = getattr(policy, "source", None) or "this path"
    differences = setting_differences(trained, config, skip)
    check_sizes(config, policy.obs_size, policy.action_size, who, describe_differences(differences))
    check_settings(trained, config, source, skip)
    check_domain(getattr(policy, "training_domain", None), config, source, allow_out_of_domain, stacklevel=4)


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
    if type(policy).__name__ == "RLlibPolicy":
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


class _AdaptedPolicy(Policy):
    """A saved ``policy`` acting on the observations of ``layout``: it keeps the wrapped policy's record
    (``source``, ``training_settings``, ``training_domain``), says in ``adaptation`` what was adapted, and resets
    the wrapped policy (a torch GRU actor's memory) where it has a ``reset``."""

    def __init__(self, policy: Any, layout: Any, action_size: int, adaptation: str) -> None:
        self.policy = policy
        self.layout = layout
        self.obs_size = layout.size
        self.action_size = action_size
        for key in ("source", "training_settings", "training_domain"):  # the wrapped policy's record
            setattr(self, key, getattr(policy, key, None))
        self.adaptation = adaptation

    def reset(self) -> None:
        """The wrapped policy's ``reset`` (a torch GRU actor's memory), where it has one."""
        reset_policy(self.policy)


class SlotAdaptedPolicy(_AdaptedPolicy):
    """A policy trained on ``W`` neighbour slots acting on an environment's observations of ``S`` slots.

    The observation (:class:`fxc_env.config.layout.ObservationLayout`) is rebuilt in the trained
    layout, row by row, and the policy (with any VecNormalize statistics it records) acts on
    that: up to ``W`` real rows give exactly the ``obs_slots=W`` observation (the same action, bit
    for bit); more than ``W`` (gain-scheduled networks only) are summed into ``W`` groups times
    ``(W + 1) / (d + 1)``, as eq. 11's gains scale with the in-degree, and warn with a
    :class:`PolicyAdaptedWarning` (docs: training.md, "Acting on other in-degrees").

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
        adaptation = f"trained with {slots} neighbour slots, acting on {layout.slots}"
        super().__init__(policy, layout, policy.action_size, adaptation)
        self.trained = ObservationLayout(slots, layout.dim, layout.limit_feature, layout.n_states)
        self.reads_any_rows = reads_any_rows

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

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions ``(..., action_size)`` for flat observations ``(..., obs_size)`` of the environment's layout
        (called as every policy is: :mod:`fxc_env.policies.protocol`)."""
        return np.asarray(self.policy(self.trained_observation(obs)), dtype=np.float64)


class PerAxisPolicy(_AdaptedPolicy):
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
        adaptation = f"trained in dim 1, acting per axis in dim {config.dim}"
        super().__init__(policy, config.layout, config.action_size, adaptation)
        self.config = config
        self.axis_layout = ObservationLayout(self.layout.slots, 1, limit_feature=self.layout.limit_feature)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions ``(..., 2 dim)`` for flat observations ``(..., obs_size)`` (called as every policy is:
        :mod:`fxc_env.policies.protocol`; a wrapped policy with a memory, a torch ``gru``, keeps one per agent
        and axis, and one agent's observation alone is refused)."""
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


class PolicyAdaptedWarning(UserWarning):
    """A saved policy was adapted to an environment it was not trained in (see :func:`load_learned_policy`)."""
