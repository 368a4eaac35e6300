"""fxc_env: fixed-time consensus of double integrators on directed graphs, as a PettingZoo environment.

Implements Liu, Zhao, Ren & Chen, "Fixed-time consensus of multiple double-integrator
systems under directed topologies: a motion-planning approach": the exact sampled-data
dynamics, the paper's controller (eq. 11) as :class:`ReferencePolicy`, and the example.

    >>> import fxc_env
    >>> env = fxc_env.parallel_env(scenario="paper_fig1")
    >>> policy = fxc_env.ReferencePolicy(env)
"""

from __future__ import annotations

from fxc_env.config import EnvConfig, make_config
from fxc_env.core.graphs import Topology, make_topology
from fxc_env.core.schedules import Schedule, make_schedule
from fxc_env.engine import ConsensusEngine
from fxc_env.fxc_consensus_v0 import env, parallel_env, raw_env
from fxc_env.reference import ReferencePolicy
from fxc_env.registration import ENV_ID, register_environments
from fxc_env.scenarios import SCENARIOS
from fxc_env.simulation import Trajectory, simulate

register_environments()

__all__ = [
    "ENV_ID",
    "SCENARIOS",
    "ConsensusEngine",
    "ConsensusVecEnv",
    "EnvConfig",
    "ReferencePolicy",
    "Schedule",
    "Topology",
    "Trajectory",
    "env",
    "make_config",
    "make_schedule",
    "make_topology",
    "parallel_env",
    "raw_env",
    "simulate",
]


def __getattr__(name: str) -> object:
    # ConsensusVecEnv pulls in stable-baselines3 and torch (about 2 s): import it on first use.
    if name == "ConsensusVecEnv":
        from fxc_env.vec_env import ConsensusVecEnv

        return ConsensusVecEnv
    raise AttributeError(f"module 'fxc_env' has no attribute {name!r}")
