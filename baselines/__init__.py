"""Classical consensus controllers (baselines) and the deadline benchmark.

Each baseline is a policy on the local observation, like :class:`fxc_env.ReferencePolicy`,
the classical ones acting in ``accel`` mode with a zero-order hold; its module docstring gives the law, its
source paper, the graph class it is proven for, and its parameters:

- :class:`LinearConsensusPolicy` (:mod:`fxc_env.baselines.linear`): Ren & Atkins 2007, gamma by Yu,
  Chen & Cao's exact gain test;
- :class:`SampledLinearPolicy` (:mod:`fxc_env.baselines.sampled`): the same law sampled at
  ``h = T_s / K`` (Cao & Ren 2010), with the reference's budget K;
- :class:`FiniteTimePolicy` (:mod:`fxc_env.baselines.finite_time`): Wang & Hong 2008 family;
- :class:`PrescribedTimePolicy` (:mod:`fxc_env.baselines.prescribed_time`): Wang, Song, Hill &
  Krstic 2019 family, gain frozen shortly before ``T_s``;
- :class:`SaturationAwarePolicy` (:mod:`fxc_env.baselines.saturation_aware`): the paper's plan
  where it fits under the input limit, a held linear law where it does not;
- :class:`MinimumTimePolicy` (:mod:`fxc_env.baselines.minimum_time`): this project's minimum-time law
  for a known fixed digraph, exact after one interval per root of the minimal polynomial of
  ``(D + I)^{-1} L`` (a ring of N: N - 1; a tree: its depth), minimum-time only where that count
  equals the radius, in ``plan`` or ``accel`` mode, raw or normalized;
- :class:`LeaderFollowerPolicy` (:mod:`fxc_env.baselines.leader_follower`): this project's time-optimal
  law for a known graph: the centre coasts, every other agent lands on its parent's coasted state in a
  (time-respecting) shortest-path tree; exact after exactly the radius, the bound for every law;
- :class:`SignallingPolicy` (:mod:`fxc_env.baselines.signalling`): this project's law on the
  energy-accuracy frontier: agents agree on the mean of the free-motion predictions by signalling
  numbers through small motions, then steer once with the minimum-energy input (a few × ``E*``);
- :class:`GraphAgnosticPolicy` (:mod:`fxc_env.baselines.graph_agnostic`): the same motions carry a
  virtual consensus iteration whose limit each agent reads off its own shortest recurrence (Yuan et
  al. 2013): exact without knowing the graph, given an upper bound ``max_agents`` on N;
- :class:`BoundedSteerPolicy` (:mod:`fxc_env.baselines.bounded_steer`): for input limits: the same motions
  flood every prediction, then each agent lands on the mid-range point with the least-peak input.

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
