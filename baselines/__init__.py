"""Classical consensus controllers (baselines) and the deadline benchmark.

Each baseline is a policy on the local observation, like :class:`fxc_env.ReferencePolicy`; its module docstring
gives the law, its source paper, the graph class it is proven for, and its parameters. The laws sit in
:mod:`fxc_env.baselines.laws`, the benchmark harness in :mod:`fxc_env.baselines.harness`. The laws are registered
once in :mod:`fxc_env.baselines.registry`; ``fxc benchmark`` (:mod:`fxc_env.baselines.harness.benchmark`) scores them
against the bounds of :mod:`fxc_env.core.optimality` (docs: benchmark.md, "Baselines and the deadline benchmark").

    >>> import fxc_env
    >>> from fxc_env import baselines
    >>> env = fxc_env.parallel_env(action_mode="accel", obs_mode="raw", schedule="uniform", n_intervals=4000)
    >>> policy = baselines.LinearConsensusPolicy(env)
"""

from __future__ import annotations

from fxc_env.baselines.harness.suite import load_policy
from fxc_env.baselines.laws.bounded_steer import BoundedSteerPolicy
from fxc_env.baselines.laws.filtering import FilteringPolicy
from fxc_env.baselines.laws.finite_time import FiniteTimePolicy
from fxc_env.baselines.laws.graph_agnostic import GraphAgnosticPolicy
from fxc_env.baselines.laws.leader_follower import LeaderFollowerPolicy
from fxc_env.baselines.laws.linear import LinearConsensusPolicy
from fxc_env.baselines.laws.minimum_time import MinimumTimePolicy
from fxc_env.baselines.laws.prescribed_time import PrescribedTimePolicy
from fxc_env.baselines.laws.sampled import SampledLinearPolicy
from fxc_env.baselines.laws.saturation_aware import SaturationAwarePolicy
from fxc_env.baselines.laws.signalling import SignallingPolicy

__all__ = [
    "BoundedSteerPolicy",
    "FilteringPolicy",
    "FiniteTimePolicy",
    "GraphAgnosticPolicy",
    "LeaderFollowerPolicy",
    "LinearConsensusPolicy",
    "MinimumTimePolicy",
    "PrescribedTimePolicy",
    "SampledLinearPolicy",
    "SaturationAwarePolicy",
    "SignallingPolicy",
    "load_policy",
]
