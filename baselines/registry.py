"""Every law the benchmark runs, registered once: the suite, ``fxc benchmark``, the optimality figure,
``fxc leaderboard`` and the tests read :data:`LAWS` and nothing else.

A law is a policy class built from a config (``cls(config)``) with the settings it runs under. To add
a baseline, write its module (a :class:`~fxc_env.baselines.laws.policy.HoldPolicy` or a plan-mode ``LawPolicy``
with ``NAME``) and call :func:`register` with it here; ``fxc benchmark --policies``, the tables, the
figures' markers and :func:`fxc_env.baselines.load_policy` pick it up.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

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
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.reference import ReferencePolicy


@dataclass(frozen=True)
class OptIn:
    """A law run with ``options`` only where ``setting`` (``obs_noise``, ``u_max`` or ``link_dropout``) is on, which it
    refuses by default. ``link_dropout`` variants run in the dropout suite (:func:`fxc_env.baselines.harness.dropout.dropout_suite`)."""

    suffix: str
    options: Mapping[str, Any]
    setting: str
    schedules: tuple[str, ...] = ("uniform",)


@dataclass(frozen=True)
class Law:
    """A registered law: its class and the environment settings it runs with.

    ``sampled``: run at every budget K (else once, at the suite's fine K, with a zero-order hold).
    ``also_on``: further schedules the optimality suite runs it on (``<name>/<schedule>``).
    ``opt_ins``: its opt-in variants (``<name>[/<schedule>]/<suffix>``). ``leaderboard``: scored
    beside BenchMARL's algorithms by ``fxc leaderboard``.
    """

    name: str
    policy: Callable[..., Any]
    sampled: bool
    schedule: str
    action_mode: str
    obs_mode: str
    also_on: tuple[str, ...] = ()
    opt_ins: tuple[OptIn, ...] = ()
    leaderboard: bool = False

    @property
    def settings(self) -> tuple[bool, str, str, str]:
        return self.sampled, self.schedule, self.action_mode, self.obs_mode

    def variants(self) -> list[tuple[str, str, str]]:
        """``(name, spec, schedule)`` of each optimality-suite variant: the schedules, then the opt-ins."""
        named = [(self.name if s == self.schedule else f"{self.name}/{s}", s) for s in (self.schedule, *self.also_on)]
        opted = [(self.opt_in_spec(opt, s), s) for opt in self.opt_ins for s in opt.schedules]
        return [(name, self.name, s) for name, s in named] + [(spec, spec, s) for spec, s in opted]

    def opt_in_spec(self, opt: OptIn, schedule: str) -> str:
        return f"{self.name}/{opt.suffix}" if schedule == self.schedule else f"{self.name}/{schedule}/{opt.suffix}"


#: Every law by name, in table order.
LAWS: dict[str, Law] = {}


def register(law: Law) -> Law:
    """Add ``law`` to :data:`LAWS` (refused when its name is taken)."""
    if law.name in LAWS:
        raise ArgumentError(f"name: a law named {law.name!r} is registered already")
    LAWS[law.name] = law
    return law


PLAN, ACCEL = ("plan", "normalized"), ("accel", "raw")
register(Law("reference", ReferencePolicy, True, "paper", *PLAN, also_on=("uniform",), leaderboard=True))
register(Law(SampledLinearPolicy.NAME, SampledLinearPolicy, True, "uniform", *ACCEL))
register(Law(LinearConsensusPolicy.NAME, LinearConsensusPolicy, False, "uniform", *ACCEL))
register(Law(FiniteTimePolicy.NAME, FiniteTimePolicy, False, "uniform", *ACCEL))
register(Law(PrescribedTimePolicy.NAME, PrescribedTimePolicy, False, "uniform", *ACCEL))
register(Law(SaturationAwarePolicy.NAME, SaturationAwarePolicy, True, "uniform", *ACCEL))
noisy = OptIn("noisy", {"allow_noise": True}, "obs_noise")
#: Every law that claims exactness refuses lost links; this runs it anyway (docs: optimality.md, "Lost links").
lossy = OptIn("lossy", {"allow_dropout": True}, "link_dropout")
register(Law("minimum_time", MinimumTimePolicy, True, "uniform", *PLAN, ("paper",), (noisy, lossy), leaderboard=True))
register(Law(LeaderFollowerPolicy.NAME, LeaderFollowerPolicy, True, "uniform", *PLAN, (), (lossy,), leaderboard=True))
limited = OptIn("limited", {"allow_limit": True}, "u_max", ("uniform", "paper"))
register(
    Law("signalling", SignallingPolicy, True, "uniform", "plan", "raw", ("paper",), (limited, lossy), leaderboard=True)
)
register(
    Law("graph_agnostic", GraphAgnosticPolicy, True, "uniform", "plan", "raw", ("paper",), (lossy,), leaderboard=True)
)
register(Law(BoundedSteerPolicy.NAME, BoundedSteerPolicy, True, "uniform", "plan", "raw", opt_ins=(lossy,)))
# Designed for obs_noise (no opt-in); off the leaderboard: its noise-free tasks are refused (switching, families,
# u_max) but rings20, where minimum_time is exact already at less energy.
register(Law(FilteringPolicy.NAME, FilteringPolicy, True, "uniform", "plan", "raw"))
