"""Entries in PettingZoo's registry: ``pettingzoo.make("parallel" | "aec", "fxc_consensus_v0", **kwargs)``.

Importing :mod:`fxc_env` registers both forms (once per process).
"""

from __future__ import annotations

ENV_ID = "fxc_consensus_v0"


def register_environments() -> None:
    """Register the parallel and AEC forms under :data:`ENV_ID` unless already there."""
    import pettingzoo

    for env_type, entry_point in (
        ("parallel", "fxc_env.envs.fxc_consensus_v0:parallel_env"),
        ("aec", "fxc_env.envs.fxc_consensus_v0:env"),
    ):
        registry = pettingzoo.parallel_registry if env_type == "parallel" else pettingzoo.aec_registry
        if ENV_ID not in registry:
            pettingzoo.register(env_type, ENV_ID, entry_point=entry_point)
