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

_EAGER_ALL = [
    "ENV_ID",
    "SCENARIOS",
    "ConsensusEngine",
    "ConsensusTorchEnv",
    "ConsensusVecEnv",
    "EnvConfig",
    "ReferenceModule",
    "ReferencePolicy",
    "Schedule",
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
}


def _law_classes() -> dict[str, type]:
    """Every registered baseline's class by name (:data:`fxc_env.baselines.LAW_CLASSES`): the baselines sit above
    the environments in the layer order, so they are imported on first use, never by ``fxc_env`` itself."""
    import importlib

    return importlib.import_module("fxc_env.baselines").LAW_CLASSES


def __getattr__(name: str) -> object:
    import importlib

    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if f"{__name__}.{name}" in _moved.MOVED:  # an old submodule read as an attribute: import it, with its warning
        return importlib.import_module(f"{__name__}.{name}")
    if name == "__all__":  # the eager names and every registered law (so `from fxc_env import *` imports the laws)
        return sorted([*_EAGER_ALL, *_law_classes()])
    if not name.startswith("_") and name in _law_classes():  # a law's class, as fxc_env.baselines exports it
        return _law_classes()[name]
    raise AttributeError(f"module 'fxc_env' has no attribute {name!r}")
