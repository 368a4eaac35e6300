"""What the deadline benchmark runs: cases, contenders and the settings each contender uses.

A **case** is a topology (family) at a size N; every contender meets the same seeded initial states on it. A
**contender** is a policy with its environment settings: sampled controllers run at every budget K of the
suite, continuous-measurement laws once, on a fine ``uniform`` schedule with a zero-order hold.
:func:`load_policy` turns a name or a saved model into a policy for one config.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.baselines.registry import LAWS
from fxc_env.config import EnvConfig, make_config
from fxc_env.config.layout import CLOCK_SIZE
from fxc_env.core.families import AnyFamily, TopologyFamily
from fxc_env.core.graphs import Topology
from fxc_env.core.models import MODEL_PARAMETERS
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.learned import SHIPPED, SHIPPED_SCHEDULES, architecture_of, load_learned_policy, pretrained_path

Policy = Callable[[np.ndarray], np.ndarray]

#: Baseline policy classes by name, and the built-in contenders' settings in table order
#: (name -> (sampled at every budget?, schedule, action mode, obs mode)): views of :data:`~fxc_env.baselines.registry.LAWS`.
BASELINES = {name: law.policy for name, law in LAWS.items() if name != "reference"}
BUILTIN_SETTINGS = {name: law.settings for name, law in LAWS.items()}


@dataclass(frozen=True)
class BenchmarkCase:
    """One topology (or topology family) at one size; ``key`` names it in tables (e.g. ``ring N=20``).

    Attributes:
        topology: a name of :data:`fxc_env.core.graphs.TOPOLOGY_NAMES`, or a family
            (:class:`~fxc_env.core.families.TopologyFamily`, a mixture), drawn per episode
            from the episode's seed.
        n_agents: N.
        period: graphs per switching period for ``random`` (1: fixed).
        mean_in_degree: of ``random`` topologies.
        topology_seed: seed of the ``random`` topology (the designer knows the graph).
        conditions: realism options of :func:`fxc_env.make_config` (``u_max``, ``obs_noise``,
            ``link_dropout``) as ``(name, value)`` pairs; empty for ideal agents.
        dim: the space dimension.
    """

    topology: str | AnyFamily | Topology
    n_agents: int
    period: int = 1
    mean_in_degree: float = 2.0
    topology_seed: int = 0
    conditions: tuple[tuple[str, float], ...] = ()
    dim: int = 1

    @property
    def family(self) -> str:
        """The topology name, with ``random`` split into fixed and switching; a family's name."""
        plane = f", dim={self.dim}" if self.dim != 1 else ""
        if isinstance(self.topology, Topology):
            return self.topology.name + plane
        if not isinstance(self.topology, str):
            return f"{self.topology.name} (drawn)" + plane
        if self.topology == "random":
            return ("random (switching)" if self.period > 1 else "random (fixed)") + plane
        return self.topology + plane

    @property
    def key(self) -> str:
        return f"{self.family} N={self.n_agents}" + "".join(f", {name}={_text(v)}" for name, v in self.conditions)

    @property
    def condition(self) -> str:
        """The realism conditions as text (``ideal`` when there are none)."""
        return ", ".join(f"{name} = {_text(value)}" for name, value in self.conditions) or "ideal"

    def config_kwargs(self) -> dict[str, Any]:
        """``make_config`` arguments of the graph (no initial state: the benchmark draws it)."""
        kwargs: dict[str, Any] = {"topology": self.topology, "n_agents": self.n_agents}
        if self.dim != 1:
            kwargs["dim"] = self.dim
        if self.topology == "random":
            kwargs.update(
                topology_period=self.period, mean_in_degree=self.mean_in_degree, topology_seed=self.topology_seed
            )
        conditions = dict(self.conditions)
        model = conditions.get("agent_model")
        parameter = MODEL_PARAMETERS.get(model)
        if parameter in conditions:  # a model's parameter travels inside its spec
            conditions["agent_model"] = {"name": model, parameter: conditions.pop(parameter)}
        return {**kwargs, **conditions}


def _text(value: Any) -> str:
    """A condition's value for tables: numbers as ``%g``, sets and ranges as ``{a, b}``."""
    if isinstance(value, tuple):
        return "{" + ", ".join(_text(v) for v in value) + "}"
    return f"{value:g}" if isinstance(value, float | int) else str(value)


@dataclass(frozen=True)
class Contender:
    """A policy and the environment settings it runs with.

    Attributes:
        name: ``reference``, a key of :data:`BASELINES`, or a label for a learned policy.
        spec: what :func:`load_policy` loads (the name, or ``[algo:]path/to/model.zip``).
        sampled: True to run at every budget K of the suite, False to run once at the
            suite's fine K (continuous-measurement laws).
        schedule, action_mode, obs_mode: environment settings.
        obs_slots: neighbour rows of the observation (a learned model's input width), or
            None for the topology's largest in-degree.
        trusted: load a saved policy whose format must unpickle (``--trust-policy-file``; see
            :func:`fxc_env.policies.learned.load_learned_policy`).
        allow_out_of_domain: run a learned policy on cases outside its recorded training domain,
            with a warning (``--allow-out-of-domain``); without it such a case is not run, and the
            table says why (:mod:`fxc_env.policies.domain`).
    """

    name: str
    spec: str
    sampled: bool
    schedule: str
    action_mode: str
    obs_mode: str
    obs_slots: int | None = None
    trusted: bool = False
    allow_out_of_domain: bool = False

    def settings(self) -> str:
        """The environment settings (but K) as text."""
        slots = "" if self.obs_slots is None else f", obs_slots = {self.obs_slots}"
        return f"{self.schedule} schedule, {self.action_mode} actions, {self.obs_mode} observations{slots}"


def builtin_contenders(names: list[str] | None = None) -> list[Contender]:
    """Every registered law (or those named), with its settings."""
    chosen = list(BUILTIN_SETTINGS) if names is None else names
    unknown = [n for n in chosen if n not in BUILTIN_SETTINGS]
    if unknown:
        raise ArgumentError(f"policies: unknown name(s) {unknown}; expected some of {tuple(BUILTIN_SETTINGS)}")
    return [Contender(n, n, *BUILTIN_SETTINGS[n]) for n in chosen]


def learned_contender(
    spec: str,
    *,
    schedule: str | None = None,
    action_mode: str = "plan",
    obs_mode: str = "normalized",
    name: str = "policy",
    trusted: bool = False,
    allow_out_of_domain: bool = False,
) -> Contender:
    """A saved policy (``pretrained``, an SB3 ``.zip``, an RLlib checkpoint or run directory) as a
    sampled contender, named after its file or directory.

    A fixed-width network's observation width fixes ``obs_slots`` (cases it does not fit are reported as not
    run); a gain-scheduled network reads any number of rows. The model is loaded here, so a missing, empty or
    corrupt file raises :class:`ArgumentError` naming ``name`` before any job runs. ``trusted`` and
    ``allow_out_of_domain`` as in :class:`Contender`.
    """
    path = model_path(spec)
    try:
        policy = load_learned_policy(path, trusted=trusted, allow_out_of_domain=allow_out_of_domain)
    except (FileNotFoundError, ArgumentError) as exc:
        raise ArgumentError(f"{name}: {str(exc).removeprefix('policy: ')}") from exc  # the loader names 'policy'
    obs_size = policy.obs_size
    slots, remainder = divmod(obs_size - CLOCK_SIZE, 3)  # remainder 1: the input-limit feature
    if remainder == 2 or slots < 1:
        raise ArgumentError(f"{name}: the model at {path} takes observations of size {obs_size}, not a dim-1 layout")
    if architecture_of(policy)[1]:  # a gain network reads any number of rows: each case's own obs_slots
        slots = None
    label = path.name if path.is_dir() else path.stem
    schedule = SHIPPED_SCHEDULES.get(spec, "paper") if schedule is None else schedule
    return Contender(
        f"learned:{label}", str(path), True, schedule, action_mode, obs_mode, slots, trusted, allow_out_of_domain
    )


def model_path(spec: str) -> Path:
    """The file of a saved model: ``pretrained``, ``generalist``, ``saturated``, ``paper_fig1`` name the shipped ones."""
    return pretrained_path(spec) if spec in SHIPPED else Path(spec)


@dataclass(frozen=True)
class Suite:
    """Cases x seeded initial states x budgets, and the fine K of continuous laws.

    Attributes:
        cases: every topology at every size.
        seeds: episode b draws its initial state from ``np.random.default_rng(seeds[b])``
            (positions U(-5, 5) m, velocities U(-2, 2) m/s per component).
        budgets: the K of sampled controllers.
        fine_intervals: the K of continuous-measurement laws (uniform, ZOH).
        settling_time: T_s in seconds.
        headline_budget: the K the headline table reports for sampled controllers.
        trace_case: the case of the disagreement-versus-time figure.
        name: ``full`` or ``quick``.
    """

    cases: tuple[BenchmarkCase, ...]
    seeds: tuple[int, ...]
    budgets: tuple[int, ...]
    fine_intervals: int
    settling_time: float = 20.0
    headline_budget: int = 200
    trace_case: BenchmarkCase = field(default_factory=lambda: BenchmarkCase("paper_fig1", 6))
    name: str = "full"

    def describe(self) -> str:
        sizes = sorted({s.n_agents for s in self.cases})
        families = list(dict.fromkeys(s.family for s in self.cases))
        return (
            f"{self.name} suite: {len(self.cases)} cases ({', '.join(families)}; N in {sizes}), "
            f"{len(self.seeds)} seeded initial states each, T_s = {self.settling_time:g} s, "
            f"budgets K in {list(self.budgets)} for sampled policies, K = {self.fine_intervals} "
            "(uniform, zero-order hold) for continuous laws"
        )


def _cases(sizes: tuple[int, ...], families: tuple[str, ...]) -> tuple[BenchmarkCase, ...]:
    cases = [BenchmarkCase("paper_fig1", 6)] if "paper_fig1" in families else []
    cases += [
        BenchmarkCase("random", n, period=3) if family == "random_switching" else BenchmarkCase(family, n)
        for n in sizes
        for family in families
        if family != "paper_fig1"
    ]
    return tuple(cases)


FAMILIES = ("paper_fig1", "ring", "path", "star", "random", "random_switching")


def full_suite(n_seeds: int = 20, fine_intervals: int = 4000) -> Suite:
    """The issue's suite: every family at N in {6, 20, 100}, K in {25, 50, 100, 200, 400}."""
    return Suite(
        cases=_cases((6, 20, 100), FAMILIES),
        seeds=tuple(range(n_seeds)),
        budgets=(25, 50, 100, 200, 400),
        fine_intervals=fine_intervals,
    )


def quick_suite(n_seeds: int = 20, fine_intervals: int = 1000) -> Suite:
    """A one-minute run: every family at N in {6, 20}, K in {25, 100, 200}, a coarser fine K."""
    return replace(
        full_suite(n_seeds, fine_intervals), cases=_cases((6, 20), FAMILIES), budgets=(25, 100, 200), name="quick"
    )


#: Realism conditions of :func:`realism_suite`: input limits, measurement noise, link losses.
REALISM_CONDITIONS: tuple[tuple[tuple[str, float], ...], ...] = (
    (),
    (("u_max", 1000.0),),
    (("u_max", 100.0),),
    (("u_max", 10.0),),
    (("obs_noise", 1e-3),),
    (("obs_noise", 1e-1),),
    (("link_dropout", 0.1),),
    (("link_dropout", 0.3),),
)


def _on_two_graphs(conditions: tuple[tuple[tuple[str, Any], ...], ...]) -> tuple[BenchmarkCase, ...]:
    """``paper_fig1``, then a random N = 20 digraph, each under every one of ``conditions``."""
    bases = (BenchmarkCase("paper_fig1", 6), BenchmarkCase("random", 20))
    return tuple(replace(base, conditions=c) for base in bases for c in conditions)


def realism_suite(n_seeds: int = 20, fine_intervals: int = 4000) -> Suite:
    """Every policy under input limits, noise and dropout on ``paper_fig1`` and a random N = 20 digraph, K = 200."""
    return Suite(
        cases=_on_two_graphs(REALISM_CONDITIONS),
        seeds=tuple(range(n_seeds)),
        budgets=(200,),
        fine_intervals=fine_intervals,
        name="realism",
    )


#: The agent models of the ``models`` suite (docs: agent-models.md, "Agent models and formations"), as ``make_config`` conditions.
MODEL_CONDITIONS = (
    (("agent_model", "single_integrator"),),
    (("agent_model", "double_integrator"),),
    (("agent_model", "integrator_chain"), ("order", 3)),
    (("agent_model", "integrator_chain"), ("order", 4)),
    (("agent_model", "damped"), ("damping", 0.5)),
    (("agent_model", "oscillator"), ("frequency", 1.0)),
)


def models_suite(n_seeds: int = 20, fine_intervals: int = 4000) -> Suite:
    """Every named agent model on ``paper_fig1`` and a random N = 20 digraph at K = 200 and 400 (the analytic
    baselines, laws for the double integrator, are reported as not run on the others)."""
    cases = _on_two_graphs(MODEL_CONDITIONS)
    return Suite(
        cases=cases,
        seeds=tuple(range(n_seeds)),
        budgets=(200, 400),
        fine_intervals=fine_intervals,
        headline_budget=200,
        trace_case=cases[2],  # paper_fig1, a chain of order 3
        name="models",
    )


#: Random digraphs of the generalisation suite: mean in-degree 1.5 to 3 (the slots of a 4-slot policy hold every draw).
GENERALISATION_RANDOM = TopologyFamily("random", mean_in_degree=(1.5, 3.0))


def generalisation_cases() -> tuple[BenchmarkCase, ...]:
    """Families and sizes a policy must handle to count as general; every graph is drawn per episode.

    ``paper_fig1``; rings and random digraphs at N = 20 and 100; a path and a star (N = 20);
    switching periods of 2 to 4 graphs dealt from rings and random digraphs (N = 20); random
    digraphs in the plane (``dim = 2``, N = 20).
    """
    ring, path, star = TopologyFamily("ring"), TopologyFamily("path"), TopologyFamily("star")
    switching_ring = TopologyFamily("ring", period=(2, 4))
    switching_random = TopologyFamily("random", mean_in_degree=(1.5, 3.0), period=(2, 4))
    return (
        BenchmarkCase("paper_fig1", 6),
        BenchmarkCase(ring, 20),
        BenchmarkCase(ring, 100),
        BenchmarkCase(GENERALISATION_RANDOM, 20),
        BenchmarkCase(GENERALISATION_RANDOM, 100),
        BenchmarkCase(path, 20),
        BenchmarkCase(star, 20),
        BenchmarkCase(switching_ring, 20),
        BenchmarkCase(switching_random, 20),
        BenchmarkCase(GENERALISATION_RANDOM, 20, dim=2),
    )


def generalisation_suite(n_seeds: int = 20, budgets: tuple[int, ...] = (200,)) -> Suite:
    """:func:`generalisation_cases` at K = 200 (T_s = 20 s), seeds ``0 .. n_seeds - 1``."""
    return Suite(
        cases=generalisation_cases(),
        seeds=tuple(range(n_seeds)),
        budgets=budgets,
        fine_intervals=1000,
        headline_budget=200 if 200 in budgets else max(budgets),
        name="generalisation",
    )


#: Noise levels and input limits of the optimality suite's floor cases (ring N = 20; docs: optimality.md, "How far from optimal").
FLOOR_NOISE = (1e-6, 1e-4, 1e-3)
FLOOR_LIMITS = (0.3, 0.5, 1.0, 10.0)


def floor_cases() -> tuple[BenchmarkCase, ...]:
    """The directed ring of 20 under each of :data:`FLOOR_NOISE` and :data:`FLOOR_LIMITS`, and ``paper_fig1`` at
    ``u_max = 10``: episodes that carry ``noise_floor`` or ``input_floor`` (:mod:`fxc_env.core.floors`)."""
    ring = BenchmarkCase("ring", 20)
    return (
        *(replace(ring, conditions=(("obs_noise", sigma),)) for sigma in FLOOR_NOISE),
        *(replace(ring, conditions=(("u_max", limit),)) for limit in FLOOR_LIMITS),
        BenchmarkCase("paper_fig1", 6, conditions=(("u_max", 10.0),)),
    )


def optimality_cases(sizes: tuple[int, ...] = (20, 100)) -> tuple[BenchmarkCase, ...]:
    """``paper_fig1`` and directed rings and random digraphs at each size (slow and fast mixing), then :func:`floor_cases`."""
    ideal = (BenchmarkCase("paper_fig1", 6), *(BenchmarkCase(f, n) for n in sizes for f in ("ring", "random")))
    return (*ideal, *floor_cases())


def optimality_suite(n_seeds: int = 20, fine_intervals: int = 4000) -> Suite:
    """How far from optimal (docs: optimality.md, "How far from optimal"): :func:`optimality_cases` at K = 200, T_s = 20 s.

    Run it with :func:`optimality_contenders`.
    """
    return Suite(
        cases=optimality_cases(),
        seeds=tuple(range(n_seeds)),
        budgets=(200,),
        fine_intervals=fine_intervals,
        trace_case=BenchmarkCase("ring", 20),
        name="optimality",
    )


def quick_optimality_suite(n_seeds: int = 5, fine_intervals: int = 1000) -> Suite:
    """:func:`optimality_suite` at N = 20 only (and ``paper_fig1``), a coarser fine K: seconds."""
    return replace(optimality_suite(n_seeds, fine_intervals), cases=optimality_cases((20,)), name="optimality-quick")


#: Laws run only by explicit opt-in where they would otherwise refuse a setting:
#: spec -> (law, keyword arguments, the setting it is run under; without that setting it is the law itself).
OPT_IN = {
    law.opt_in_spec(o, s): (law.name, o.options, o.setting)
    for law in LAWS.values()
    for o in law.opt_ins
    for s in o.schedules
}


def optimality_variants(law: Any, dropout: bool = False) -> list[tuple[str, str, str]]:
    """``law.variants()`` but those opted in under ``link_dropout`` (with ``dropout``: only those), which the
    optimality suite has no case for (:mod:`fxc_env.baselines.harness.dropout` runs them)."""
    return [v for v in law.variants() if (OPT_IN.get(v[1], ("", {}, ""))[2] == "link_dropout") == dropout]


def optimality_contenders() -> list[Contender]:
    """Every registered law (:data:`~fxc_env.baselines.registry.LAWS`): those with further schedules or opt-ins
    (:data:`OPT_IN`, run only where their setting is on) first, with every variant, then the others."""
    laws = sorted(LAWS.values(), key=lambda law: len(optimality_variants(law)) == 1)
    return [
        Contender(name, spec, law.sampled, schedule, law.action_mode, law.obs_mode)
        for law in laws
        for name, spec, schedule in optimality_variants(law)
    ]


def contender_config(contender: Contender, case: BenchmarkCase, n_intervals: int, settling_time: float) -> EnvConfig:
    """The environment a contender meets on a case at K intervals."""
    return make_config(
        **case.config_kwargs(),
        settling_time=settling_time,
        n_intervals=n_intervals,
        schedule=contender.schedule,
        action_mode=contender.action_mode,
        obs_mode=contender.obs_mode,
        obs_slots=contender.obs_slots,
    )


def load_policy(spec: str, config: EnvConfig, trusted: bool = False, allow_out_of_domain: bool = False) -> Policy:
    """A policy for ``config``: ``reference``, a baseline name, ``pretrained`` or a saved policy's path.

    Saved policies load through :func:`fxc_env.policies.learned.load_learned_policy`. Raises
    :class:`ArgumentError` naming ``policy`` when the spec is unknown, nothing is saved at the path, the file
    is not a readable model, the model does not fit, or ``config`` lies outside its training domain;
    ``trusted`` and ``allow_out_of_domain`` as in :class:`Contender`.
    """
    if spec in LAWS:
        return LAWS[spec].policy(config)
    if spec in OPT_IN:
        name, options, setting = OPT_IN[spec]
        off = {"obs_noise": config.obs_noise == 0, "u_max": config.u_max_choices is None}
        if off.get(setting, config.link_dropout == 0):
            raise ArgumentError(f"{setting}: {spec} is {name} opted in under {setting}; without it it is {name} itself")
        return LAWS[name].policy(config, **options)
    path = model_path(spec)
    if spec in SHIPPED or path.suffix == ".zip" or path.exists():
        try:
            return load_learned_policy(path, config, trusted=trusted, allow_out_of_domain=allow_out_of_domain)
        except FileNotFoundError as exc:
            raise ArgumentError(str(exc)) from exc
    raise ArgumentError(
        f"policy: unknown {spec!r}; expected 'reference', one of {tuple(BASELINES)}, a shipped policy "
        f"{tuple(SHIPPED)} or the path of a saved policy (an SB3 model .zip, a torch policy .pt or its run "
        "directory, a gain schedule .npz, an RLlib checkpoint or run directory)"
    )
