"""Whether a saved policy fits an environment: its sizes, the settings it was trained for, its width.

:func:`check_fit` refuses an environment whose observation or action size, or whose recorded
training settings (:data:`CHECKED_SETTINGS`: action and observation modes, the input-limit
feature, the agent model, dim, obs_slots), differ from the policy's, naming the setting and both
values, and one outside its training domain (:mod:`fxc_env.policies.domain`). Every reader
(:mod:`fxc_env.policies.learned`, :mod:`~fxc_env.policies.torch_policy`,
:mod:`~fxc_env.policies.interval_gains`) calls these.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fxc_env.config.layout import CLOCK_SIZE
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import check_domain

#: The settings of the training environment a loaded policy must meet (README, "Training learned
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
    from fxc_env.config import config_of

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
    from fxc_env.config import make_config

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
