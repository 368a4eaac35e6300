"""The batched engine: B episodes × N agents advanced interval by interval in closed form.

Layer 3 (above :mod:`fxc_env.config`): every environment front end (PettingZoo, the SB3 VecEnv,
the TorchRL env) and the training loops drive one :class:`ConsensusEngine`, which wires named
parts, one module each (docs: architecture.md, "Layers").
"""

from __future__ import annotations

from fxc_env.engine.consensus_engine import (
    ConsensusEngine,
    EpisodeDraw,
    StepOutcome,
    limit_feature,
    state_disagreement,
    to_host,
)
from fxc_env.engine.draws import with_initial_state

__all__ = [
    "ConsensusEngine",
    "EpisodeDraw",
    "StepOutcome",
    "limit_feature",
    "state_disagreement",
    "to_host",
    "with_initial_state",
]
