"""Named, versioned tasks: the settings, evaluation seeds and budget K of a benchmark, frozen under one name.

A task is what a results table cites: ``fxc/rings20-v1`` is the directed ring of N = 20
agents with ``T_s = 20`` s, K = 200 sampling intervals and evaluation seeds 1000 .. 1019.
Its settings never change; a change of settings is a new version: ``fxc/rings20-v2`` is the
same ring at K = 50 with ``action_mode="plan_balanced"`` (both action parts in the deadline
metric's units, a ``±1`` box) for learning. The same names
work in every front end, the ``fxc/`` prefix optional (docs: tasks/index.md, "Named tasks").
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from fxc_env.core.validation import ArgumentError

#: The namespace of the tasks' ids in PettingZoo's registry and BenchMARL (``fxc/<task>``).
NAMESPACE = "fxc"

#: The evaluation seeds of every v1 task: 20 episodes, disjoint from the training seeds 0, 1, 2, ...
EVALUATION_SEEDS_V1 = tuple(range(1000, 1020))


@dataclass(frozen=True)
class NamedTask:
    """One frozen task: environment keyword arguments (K included) and the seeds it is scored on.

    Attributes:
        name: the task's name without its version (``"rings20"``).
        version: the version, ``-v<version>`` in the id; a change of settings is a new version.
        settings: the keyword arguments of :func:`fxc_env.parallel_env` (and of
            :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv`), read-only; ``n_intervals`` is K.
        eval_seeds: the seeds of the evaluation episodes.
        description: one line for tables and ``--help``.
    """

    name: str
    version: int
    settings: Mapping[str, Any]
    eval_seeds: tuple[int, ...]
    description: str

    @property
    def id(self) -> str:
        """``"<name>-v<version>"``: BenchMARL's task name and ``fxc evaluate --task``'s value."""
        return f"{self.name}-v{self.version}"

    @property
    def full_id(self) -> str:
        """``"fxc/<name>-v<version>"``: the id in PettingZoo's registry and BenchMARL's ``task=``."""
        return f"{NAMESPACE}/{self.id}"

    @property
    def n_intervals(self) -> int:
        """K, the sampling intervals of an episode (one step each)."""
        return int(self.settings["n_intervals"])

    def kwargs(self) -> dict[str, Any]:
        """A fresh (deep) copy of the settings, safe to edit."""
        return copy.deepcopy(dict(self.settings))


def _task(name: str, version: int, description: str, **settings: Any) -> NamedTask:
    return NamedTask(name, version, MappingProxyType(settings), EVALUATION_SEEDS_V1, description)


_TASKS = (
    _task(
        "paper_fig1",
        1,
        "the paper's example (six agents, its initial state, the assumed Fig. 1 switching), T_s = 20 s, K = 200",
        scenario="paper_fig1",
        n_intervals=200,
    ),
    _task(
        "rings20",
        1,
        "a fixed directed ring of N = 20 agents, seeded initial states, T_s = 20 s, K = 200",
        n_agents=20,
        topology="ring",
        settling_time=20.0,
        n_intervals=200,
    ),
    _task(
        "generalist",
        1,
        "a new graph every episode (rings, paths, stars, random digraphs on N = 20, fixed or switching), K = 200",
        scenario="generalist",
        n_intervals=200,
    ),
    _task(
        "saturated",
        1,
        "input limits u_max in {10, 100, 1000} on switching rings and random digraphs (N = 6, uniform schedule), "
        "K = 200",
        scenario="saturated",
        n_intervals=200,
    ),
)

#: The v2 tasks' interface: plans whose two parts move ``D(T_s)/D(0)`` alike per unit on every interval,
#: in a box ``±1`` that holds the reference (docs: environment.md, "Conditioning of the action"), at K = 50.
V2_SETTINGS = MappingProxyType({"action_mode": "plan_balanced", "action_bound": 1.0, "n_intervals": 50})

#: The v2 tasks' own settings besides :data:`V2_SETTINGS`, by name. ``generalist``: a reward floor of 1e-3 D(0), so
#: that the return (at most ln 1000) stops paying for pushing the easy episodes (stars, many random digraphs: the
#: reference reaches 1e-8 there) further below 1e-3 while the task's directed paths get worse; the score
#: D(T_s)/D(0) is the same (docs: results.md, "IPPO on generalist-v2").
V2_OWN_SETTINGS = MappingProxyType({"generalist": MappingProxyType({"reward_floor": 1e-3})})

_TASKS += tuple(
    _task(
        task.name,
        2,
        task.description.replace("K = 200", "K = 50, plan_balanced actions in a ±1 box")
        + "".join(f", {key} = {value:g}" for key, value in V2_OWN_SETTINGS.get(task.name, {}).items()),
        **{**task.settings, **V2_SETTINGS, **V2_OWN_SETTINGS.get(task.name, {})},
    )
    for task in _TASKS
)

#: Every task by id (``"rings20-v1"``), read-only.
TASKS: Mapping[str, NamedTask] = MappingProxyType({task.id: task for task in _TASKS})


def get_task(name: Any, argument: str = "task") -> NamedTask:
    """The task ``name`` (``"rings20-v1"`` or ``"fxc/rings20-v1"``); anything else raises naming ``argument``."""
    if isinstance(name, str):
        key = name.removeprefix(f"{NAMESPACE}/")
        if key in TASKS:
            return TASKS[key]
        spelled = "full_id" if key != name else "id"  # the versions as the name was given: "fxc/..." or bare
        versions = [getattr(task, spelled) for task in TASKS.values() if task.name == key]
        if versions:
            raise ArgumentError(
                f"{argument}: a task name carries its version (its settings are frozen under it): "
                f"give one of {versions}, got {name!r}"
            )
    raise ArgumentError(f"{argument}: expected one of {tuple(TASKS)} (optionally as 'fxc/<task>'), got {name!r}")


def task_kwargs(name: Any) -> dict[str, Any]:
    """The keyword arguments of task ``name``'s environment (a fresh dict): ``parallel_env(**task_kwargs(...))``."""
    return get_task(name).kwargs()
