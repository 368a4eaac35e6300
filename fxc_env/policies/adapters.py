"""A saved policy acting where it was not trained: on another number of neighbour slots
(:class:`SlotAdaptedPolicy`, :func:`adapt_slots`) or per axis in ``dim > 1`` (:class:`PerAxisPolicy`).

:func:`fxc_env.policies.learned.load_learned_policy` chooses them (README, "Training learned policies").
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError
from fxc_env.policies.domain import check_domain
from fxc_env.policies.fit import architecture_of, largest_in_degree


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
