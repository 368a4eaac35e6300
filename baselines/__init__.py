"""Classical consensus controllers (baselines) and the deadline benchmark.

Each baseline is a policy on the local observation, like :class:`fxc_env.ReferencePolicy`,
the classical ones acting in ``accel`` mode with a zero-order hold; its module docstring gives the law, its
source paper, the graph class it is proven for, and its parameters. The laws, their settings and their
opt-in variants are registered once in :mod:`fxc_env.baselines.registry`:
:class:`SampledLinearPolicy`, :class:`LinearConsensusPolicy`, :class:`FiniteTimePolicy`,
:class:`PrescribedTimePolicy`, :class:`SaturationAwarePolicy`, :class:`MinimumTimePolicy`,
:class:`LeaderFollowerPolicy`, :class:`SignallingPolicy`, :class:`GraphAgnosticPolicy` and
:class:`BoundedSteerPolicy`.

:mod:`fxc_env.core.optimality` gives the bounds every law is measured against: the least energy
``E*`` of an exact consensus at ``T_s`` and the fewest intervals (the radius, for every law; the
all-roots bound for laws whose value depends on every root).

``fxc benchmark`` (:mod:`fxc_env.baselines.benchmark`) scores them, the reference and learned
policies (:func:`load_policy`) on one suite (:mod:`fxc_env.baselines.suite`).

    >>> import fxc_env
    >>> from fxc_env import baselines
    >>> env = fxc_env.parallel_env(action_mode="accel", obs_mode="raw", schedule="uniform", n_intervals=4000)
    >>> policy = baselines.LinearConsensusPolicy(env)
"""

from __future__ import annotations

from fxc_env.baselines.bounded_steer import BoundedSteerPolicy
from fxc_env.baselines.finite_time import FiniteTimePolicy
from fxc_env.baselines.graph_agnostic import GraphAgnosticPolicy
from fxc_env.baselines.leader_follower import LeaderFollowerPolicy
from fxc_env.baselines.linear import LinearConsensusPolicy
from fxc_env.baselines.minimum_time import MinimumTimePolicy
from fxc_env.baselines.prescribed_time import PrescribedTimePolicy
from fxc_env.baselines.sampled import SampledLinearPolicy
from fxc_env.baselines.saturation_aware import SaturationAwarePolicy
from fxc_env.baselines.signalling import SignallingPolicy
from fxc_env.baselines.suite import load_policy

__all__ = [
    "BoundedSteerPolicy",
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
