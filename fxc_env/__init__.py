"""fxc_env: fixed-time consensus of double integrators on directed graphs, as a PettingZoo environment.

Implements Liu, Zhao, Ren & Chen, "Fixed-time consensus of multiple double-integrator
systems under directed topologies: a motion-planning approach": the exact sampled-data
dynamics, the paper's controller (eq. 11) as :class:`ReferencePolicy`, and the example.

    >>> import fxc_env
    >>> env = fxc_env.parallel_env(scenario="paper_fig1")
    >>> policy = fxc_env.ReferencePolicy(env)
    >>> episode = fxc_env.rollout(env, policy, seed=0)  # policy(observations) each step: {agent: action}
"""

from __future__ import annotations

import sys

from fxc_env import _moved
from fxc_env.analysis.simulation import Trajectory, simulate
from fxc_env.config import EnvConfig, make_config
from fxc_env.config.scenarios import SCENARIOS
from fxc_env.core.graphs import Topology, make_topology
from fxc_env.core.schedules import Schedule, make_schedule
from fxc_env.engine import ConsensusEngine
from fxc_env.envs import fxc_consensus_v0  # the versioned module, as PettingZoo's suites export theirs
from fxc_env.envs.fxc_consensus_v0 import env, parallel_env, raw_env
from fxc_env.envs.registration import ENV_ID, register_environments
from fxc_env.policies.learned import load_learned_policy
from fxc_env.policies.protocol import rollout
from fxc_env.policies.reference import ReferencePolicy

register_environments()
# The versioned module also imports at its public path, as PettingZoo's suites' modules do (no file stands there).
sys.modules.setdefault(f"{__name__}.fxc_consensus_v0", fxc_consensus_v0)
_moved.install()  # the previous release's module paths, with a DeprecationWarning naming the new ones

__all__ = [
    "ENV_ID",
    "SCENARIOS",
    "BoundedSteerPolicy",
    "ConsensusEngine",
    "ConsensusTorchEnv",
    "ConsensusVecEnv",
    "EnvConfig",
    "FilteringPolicy",
    "FiniteTimePolicy",
    "GraphAgnosticPolicy",
    "LeaderFollowerPolicy",
    "LinearConsensusPolicy",
    "MinimumTimePolicy",
    "PrescribedTimePolicy",
    "ReferenceModule",
    "ReferencePolicy",
    "SampledLinearPolicy",
    "SaturationAwarePolicy",
    "Schedule",
    "SignallingPolicy",
    "Topology",
    "Trajectory",
    "env",
    "fxc_consensus_v0",
    "load_learned_policy",
    "make_config",
    "make_schedule",
    "make_topology",
    "parallel_env",
    "raw_env",
    "reference_policy",
    "rollout",
    "simulate",
]


#: Names that pull in heavy optional packages, imported on first use: module path of each.
_LAZY = {
    "ConsensusVecEnv": "fxc_env.envs.vec_env",  # stable-baselines3 and torch (about 2 s)
    "ConsensusTorchEnv": "fxc_env.envs.torch_env",  # torchrl (the torchrl extra)
    "reference_policy": "fxc_env.policies.torchrl_reference",
    "ReferenceModule": "fxc_env.policies.torchrl_reference",
    # The baselines sit above the environments in the layer order: imported on first use, never by fxc_env itself.
    "BoundedSteerPolicy": "fxc_env.baselines",
    "FilteringPolicy": "fxc_env.baselines",
    "FiniteTimePolicy": "fxc_env.baselines",
    "GraphAgnosticPolicy": "fxc_env.baselines",
    "LeaderFollowerPolicy": "fxc_env.baselines",
    "LinearConsensusPolicy": "fxc_env.baselines",
    "MinimumTimePolicy": "fxc_env.baselines",
    "PrescribedTimePolicy": "fxc_env.baselines",
    "SampledLinearPolicy": "fxc_env.baselines",
    "SaturationAwarePolicy": "fxc_env.baselines",
    "SignallingPolicy": "fxc_env.baselines",
}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    if f"{__name__}.{name}" in _moved.MOVED:  # an old submodule read as an attribute: import it, with its warning
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module 'fxc_env' has no attribute {name!r}")
