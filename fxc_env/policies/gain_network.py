"""A gain-scheduled policy network for stable-baselines3: actions linear in the neighbour rows.

``alpha_i = sum_j G(context_i)_j row_ij`` with ``G_j`` a 2 x 2 matrix per neighbour slot j and the
context the mask, clock and limit feature; the paper's controller (eq. 11) is
``G_j = [[1, 1], [0, 1]] / (d_i + 1)``. One axis only (``dim = 1``); in the plane it acts per axis
(:class:`fxc_env.policies.learned.PerAxisPolicy`). Why and how: docs: training.md, "The
gain-scheduled network".

Use it as ``policy: fxc_env.policies.gain_network.GainScheduledPolicy`` in the hyperparameter file.
"""

from __future__ import annotations

from typing import Any

import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn

from fxc_env.config.layout import CLOCK_SIZE
from fxc_env.policies.networks import mlp


class GainScheduledExtractor(nn.Module):
    """SB3's ``mlp_extractor`` slot: the actor's "latent" is the action itself, the critic an MLP.

    Args:
        obs_size: length of the flat observation ``[rows (2 per slot) | mask (1 per slot) | clock (3) | limit?]``.
        hidden: widths of the hidden layers of the gain network and of the value network.
    """

    def __init__(self, obs_size: int, hidden: tuple[int, ...] = (64, 64)) -> None:
        super().__init__()
        slots, remainder = divmod(obs_size - CLOCK_SIZE, 3)
        if remainder not in (0, 1) or slots < 1:
            raise ValueError(
                f"GainScheduledPolicy: observations of size {obs_size} are not a one-axis layout "
                "(3 slots + 3 clock [+ 1 limit]); use it with dim = 1"
            )
        self.slots = slots
        self.rows_end = 2 * slots
        context_size = obs_size - self.rows_end
        self.latent_dim_pi = 2
        self.latent_dim_vf = hidden[-1]
        self.gains = mlp(context_size, 4 * slots, hidden)
        self.value = mlp(obs_size, None, hidden)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self._linear_law(self.gains, features)

    def _linear_law(self, gain_network: nn.Module, features: torch.Tensor) -> torch.Tensor:
        """``sum_j G_j row_ij`` with ``G`` from ``gain_network`` on the context, ``(..., 2)``."""
        lead = features.shape[:-1]
        rows = features[..., : self.rows_end].reshape(*lead, self.slots, 2, 1)
        gains = gain_network(features[..., self.rows_end :]).reshape(*lead, self.slots, 2, 2)
        # The gain from position rows into the velocity plan is in units of T / T_s (docs: training.md, "The gain-scheduled network").
        scale = torch.ones_like(gains)
        scale[..., 1, 0] = features[..., self.rows_end + self.slots + 1, None]
        return ((gains * scale) @ rows).sum(dim=-3)[..., 0]

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.value(features)


class GainScheduledPolicy(ActorCriticPolicy):
    """SB3 actor-critic policy whose mean action is :class:`GainScheduledExtractor`'s (see the module)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        net_arch = kwargs.pop("net_arch", None)
        self._hidden = tuple(net_arch) if isinstance(net_arch, list | tuple) else (64, 64)
        kwargs["ortho_init"] = False  # the gain network starts at zero gains (below), not orthogonal
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = GainScheduledExtractor(self.features_dim, self._hidden)

    def _build(self, lr_schedule: Any) -> None:
        super()._build(lr_schedule)
        self.action_net = nn.Identity()  # the extractor already returns the action mean
        for name in ("gains", "hold_gains"):  # every gain network starts at zero gains
            if hasattr(self.mlp_extractor, name):
                nn.init.zeros_(getattr(self.mlp_extractor, name)[-1].weight)
                nn.init.zeros_(getattr(self.mlp_extractor, name)[-1].bias)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)


class GatedGainExtractor(GainScheduledExtractor):
    """Two gain-scheduled laws and a gate between them, for policies that see an input limit.

    ``alpha = gate * plan + (1 - gate) * hold``: both are :class:`GainScheduledExtractor`'s
    linear laws (their own gain networks), and the gate compares the input the first one
    needs with the limit, ``sigmoid(k (log10 rho - log10 need))``, where ``rho = u_max T^2 / s_i``
    comes from the observation's limit entry and ``need`` is the largest of
    ``|6 plan_x - 2 plan_v|`` and ``|4 plan_v - 6 plan_x|`` (the plan's end inputs in units of
    ``s_i / T^2``). The switch of the saturation-aware law (``fxc_env.baselines.laws.saturation_aware``:
    the paper's plan where it fits, a held linear law where it does not) is one setting of
    it; ``k`` is learned (it starts at 20, a decade either side of the threshold is then
    decided). The gate depends on the rows, which a single gain network cannot express.
    """

    def __init__(self, obs_size: int, hidden: tuple[int, ...] = (64, 64)) -> None:
        super().__init__(obs_size, hidden)
        if (obs_size - CLOCK_SIZE) % 3 != 1:
            raise ValueError(f"GatedGainPolicy: observations of size {obs_size} have no input-limit entry")
        self.hold_gains = mlp(obs_size - self.rows_end, 4 * self.slots, hidden)
        self.sharpness = nn.Parameter(torch.tensor(20.0))

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        plan = self._linear_law(self.gains, features)
        hold = self._linear_law(self.hold_gains, features)
        entry = features[..., -1:].clamp(-1.0 + 1e-6, 1.0 - 1e-6)
        log_rho = entry / (1.0 - entry.abs())
        need = torch.maximum(
            (6 * plan[..., :1] - 2 * plan[..., 1:]).abs(), (4 * plan[..., 1:] - 6 * plan[..., :1]).abs()
        )
        gate = torch.sigmoid(self.sharpness * (log_rho - torch.log10(need + 1e-30)))
        return gate * plan + (1.0 - gate) * hold


class GatedGainPolicy(GainScheduledPolicy):
    """SB3 actor-critic policy whose mean action is :class:`GatedGainExtractor`'s."""

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = GatedGainExtractor(self.features_dim, self._hidden)
