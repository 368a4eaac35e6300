"""The paper's controller, eq. (11), for TorchRL: a torch module and its ``TensorDictModule``.

``env.rollout(K, reference_policy(env))`` plays an episode of
:class:`fxc_env.envs.torch_env.ConsensusTorchEnv` with the reference. Needs
``pip install "fxc-env[torchrl]"``.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict.nn import TensorDictModule

from fxc_env.config import EnvConfig
from fxc_env.policies.reference import ReferencePolicy

#: The agent group of :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv`'s TensorDicts.
GROUP = "agents"


class ReferenceModule(torch.nn.Module):
    """The paper's controller, eq. (11), as a torch module: observations ``[..., obs_size]`` to actions ``[..., 2 dim]``.

    The same arithmetic as :class:`fxc_env.ReferencePolicy` (it calls its array-API path),
    on any device and dtype, with no parameters.
    """

    def __init__(self, config: EnvConfig | Any) -> None:
        super().__init__()
        self.policy = ReferencePolicy(config)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.policy.act(observation)


def reference_policy(env: Any) -> TensorDictModule:
    """:class:`ReferenceModule` for ``env`` (a ``ConsensusTorchEnv``): reads ``("agents", "observation")``, writes ``("agents", "action")``."""
    return TensorDictModule(ReferenceModule(env.config), in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "action")])
