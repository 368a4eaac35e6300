"""The hyperparameter entries of the torch back ends, checked: ``torch_ppo`` (:class:`PPOSettings`) and
``diff_apg`` (:class:`DiffSettings`), read by :func:`fxc_env.training.args.check_train_args` before any work
and by the trainers of :mod:`fxc_env.training.backends.torch_ppo` and :mod:`fxc_env.training.backends.diff_train`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from fxc_env.config import EnvConfig
from fxc_env.core import validation
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.networks import ACTIVATIONS
from fxc_env.policies.torch_memory import GRU_INPUTS

#: The losses of :class:`DiffSettings` (see :mod:`fxc_env.training.backends.diff_train`).
LOSSES = ("log_error", "return")


@dataclasses.dataclass(frozen=True)
class PPOSettings:
    """The ``torch_ppo`` entry of the hyperparameter file (every key optional)."""

    n_envs: int = 256
    """B, the parallel episodes (``--n-envs`` overrides it)."""
    rollout_steps: int = 200
    """T, environment steps per rollout: K or a divisor of K."""
    learning_rate: float = 3.0e-4
    epochs: int = 4
    """Passes over a rollout's agent-steps per update."""
    minibatch_size: int = 8192
    """Agent-steps per gradient step."""
    gamma: float = 1.0
    """1: the per-step rewards telescope to the episode's log reduction ln D(0)/D(T_s)."""
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    hidden: tuple[int, ...] = (64, 64)
    """Widths of the hidden layers of the policy's mean and of the critic (separate networks)."""
    activation: str = "tanh"
    log_std_init: float = -2.0
    """Initial log standard deviation of the exploration noise (state independent, learned)."""
    actor_out_gain: float = 0.01
    """Orthogonal gain of the ``mlp`` actor's output layer; 0 starts it at exactly zero (with
    ``action_mode: residual`` the untrained policy is then the reference; docs: results.md, "PPO from scratch")."""
    normalize_advantage: bool = True
    gru_size: int = 64
    """``--policy-arch gru``: the width of the GRU's hidden state."""
    gru_input: str = "observation"
    """``--policy-arch gru``: what the GRU reads, ``observation`` or ``schedule`` (:class:`RecurrentActor`)."""
    embed_size: int = 64
    """``--policy-arch gnn``: the width of each agent's embedding."""
    message_rounds: int = 2
    """``--policy-arch gnn``: rounds of messages (each reaches one hop further upstream)."""

    @classmethod
    def from_mapping(
        cls, entry: Mapping[str, Any], config: EnvConfig, *, name: str = "hyperparams", section: str = "torch_ppo"
    ) -> PPOSettings:
        """Checked settings from a hyperparameter entry; raise naming ``name: <section>.<key>``."""
        known = {field.name for field in dataclasses.fields(cls)}
        unknown = sorted(set(entry) - known)
        if unknown:
            raise ArgumentError(f"{name}: {section} has no setting {unknown[0]!r}; expected some of {sorted(known)}")
        values = {**{f.name: f.default for f in dataclasses.fields(cls)}, **entry}

        def key(k: str) -> str:
            return f"{name}: {section}.{k}"

        k_intervals = config.n_intervals
        for field in ("n_envs", "rollout_steps", "epochs", "minibatch_size", "gru_size", "embed_size"):
            validation.integer(key(field), values[field], 1)
        validation.integer(key("message_rounds"), values["message_rounds"], 1, 8)
        if k_intervals % values["rollout_steps"]:
            raise ArgumentError(
                f"{key('rollout_steps')}: expected K = {k_intervals} or a divisor of it, got {values['rollout_steps']}"
            )
        for field in ("learning_rate", "clip_range", "max_grad_norm"):
            validation.real(key(field), values[field], positive=True)
        for field in ("gamma", "gae_lambda"):
            validation.real(key(field), values[field], 0.0, 1.0)
        for field in ("ent_coef", "vf_coef", "log_std_init"):
            validation.real(key(field), values[field])
        validation.real(key("actor_out_gain"), values["actor_out_gain"], 0.0)
        hidden = values["hidden"]
        if not isinstance(hidden, list | tuple) or not hidden:
            raise ArgumentError(f"{key('hidden')}: expected a list of layer widths, got {hidden!r}")
        for width in hidden:
            validation.integer(key("hidden"), width, 1, 1_000_000)
        validation.choice(key("activation"), values["activation"], tuple(ACTIVATIONS))
        validation.choice(key("gru_input"), values["gru_input"], GRU_INPUTS)
        if not isinstance(values["normalize_advantage"], bool):
            raise ArgumentError(f"{key('normalize_advantage')}: expected true or false")
        values["hidden"] = tuple(int(w) for w in hidden)
        for field in ("learning_rate", "clip_range", "max_grad_norm", "gamma", "gae_lambda", "ent_coef", "vf_coef"):
            values[field] = float(values[field])
        values.update(log_std_init=float(values["log_std_init"]), actor_out_gain=float(values["actor_out_gain"]))
        return cls(**values)


@dataclasses.dataclass(frozen=True)
class DiffSettings:
    """The ``diff_apg`` entry of the hyperparameter file (every key optional)."""

    n_envs: int = 64
    """B, the parallel episodes (``--n-envs`` overrides it)."""
    window: int | None = None
    """Steps per truncated back-propagation window: K or a divisor of K; None (the default): the whole episode."""
    loss: str = "log_error"
    """``log_error`` (mean ln D(T_s)/D(0)) or ``return`` (minus the mean return)."""
    learning_rate: float = 1.0e-3
    max_grad_norm: float = 1.0
    """The gradient's norm is clipped to this before each Adam step."""
    hidden: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    gru_size: int = 64
    gru_input: str = "observation"
    embed_size: int = 64
    message_rounds: int = 2

    #: The keys the actor shares with the torch back end (checked by :meth:`PPOSettings.from_mapping`).
    SHARED = ("n_envs", "learning_rate", "max_grad_norm", "hidden", "activation", "gru_size", "gru_input")
    SHARED += ("embed_size", "message_rounds")

    @classmethod
    def from_mapping(cls, entry: Mapping[str, Any], config: EnvConfig, *, name: str = "hyperparams") -> DiffSettings:
        """Checked settings from a hyperparameter entry; raise naming ``name: diff_apg.<key>``."""
        known = sorted(field.name for field in dataclasses.fields(cls))
        unknown = sorted(set(entry) - set(known))
        if unknown:
            raise ArgumentError(f"{name}: diff_apg has no setting {unknown[0]!r}; expected some of {known}")
        k_intervals = config.n_intervals
        window = entry.get("window")
        if window is not None:
            validation.integer(f"{name}: diff_apg.window", window, 1, k_intervals)
            if k_intervals % window:
                raise ArgumentError(
                    f"{name}: diff_apg.window: expected K = {k_intervals} or a divisor of it (or null), got {window}"
                )
        loss = validation.choice(f"{name}: diff_apg.loss", entry.get("loss", cls.loss), LOSSES)
        defaults = {field.name: field.default for field in dataclasses.fields(cls)}  # this class's, not PPO's
        shared = PPOSettings.from_mapping(
            {key: entry.get(key, defaults[key]) for key in cls.SHARED} | {"rollout_steps": window or k_intervals},
            config,
            name=name,
            section="diff_apg",
        )
        return cls(window=window, loss=loss, **{key: getattr(shared, key) for key in cls.SHARED})

    def ppo(self, k_intervals: int) -> PPOSettings:
        """The torch back end's settings that build the same actor (its trainer holds the networks and files)."""
        shared = {key: getattr(self, key) for key in self.SHARED}
        return PPOSettings(rollout_steps=self.window or k_intervals, **shared)
