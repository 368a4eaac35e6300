"""Every network the package builds: :func:`mlp` and the actors of SB3 policy files.

The torch back ends' actors and critics (:mod:`fxc_env.policies.torch_memory`,
:mod:`fxc_env.training.backends.torch_ppo`), the gain-scheduled SB3 networks
(:mod:`fxc_env.policies.gain_network`), the actors read back from SB3 files
(:mod:`fxc_env.policies.sb3_files`) and the timing networks of ``fxc speed`` all come from here.
"""

from __future__ import annotations

import math

from torch import nn

#: Activations a torch back end's network may use (the ``activation`` setting).
ACTIVATIONS: dict[str, type[nn.Module]] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}
#: Activations an SB3 policy file may name (``activation_fn``).
SB3_ACTIVATIONS: dict[str, type[nn.Module]] = {**ACTIVATIONS, "leaky_relu": nn.LeakyReLU}


def mlp(
    inputs: int, outputs: int | None, hidden: tuple[int, ...], activation: str = "tanh", out_gain: float | None = None
) -> nn.Sequential:
    """``Linear`` + activation layers, then a ``Linear`` to ``outputs`` (none when None).

    With ``out_gain`` the layers are initialised orthogonally (SB3's gains: sqrt 2, then ``out_gain``)
    and their biases zeroed; without it they keep torch's default initialisation.
    """
    layers: list[nn.Module] = []
    width = inputs
    for size in hidden:
        layers += [_linear(width, size, None if out_gain is None else math.sqrt(2.0)), SB3_ACTIVATIONS[activation]()]
        width = size
    if outputs is not None:
        layers.append(_linear(width, outputs, out_gain))
    return nn.Sequential(*layers)


def _linear(inputs: int, outputs: int, gain: float | None) -> nn.Linear:
    layer = nn.Linear(inputs, outputs)
    if gain is not None:
        nn.init.orthogonal_(layer.weight, gain)
        nn.init.zeros_(layer.bias)
    return layer


class MeanActor(nn.Module):
    """SB3's actor mean: ``mean(latent(obs))`` (PPO's ``action_net(policy_net)``, SAC's ``mu(latent_pi)``)."""

    def __init__(self, latent: nn.Module, mean: nn.Module) -> None:
        super().__init__()
        self.latent, self.mean = latent, mean

    def forward(self, obs):
        return self.mean(self.latent(obs))


class GainActor(nn.Module):
    """The gain networks' action mean: the extractor's ``forward_actor`` (their ``action_net`` is the identity)."""

    def __init__(self, extractor: nn.Module) -> None:
        super().__init__()
        self.extractor = extractor

    def forward(self, obs):
        return self.extractor.forward_actor(obs)
