"""Entries in PettingZoo's registry: ``pettingzoo.make("parallel" | "aec", "fxc_consensus_v0", **kwargs)``.

Importing :mod:`fxc_env` registers both forms (once per process), and both forms of every named
task (:data:`fxc_env.config.tasks.TASKS`) under its id: ``pettingzoo.make("parallel", "fxc/rings20-v1")``.
A task's id without its version (``"fxc/rings20"``), which PettingZoo would resolve to the newest
version, is refused as every other front end refuses it (:func:`fxc_env.config.tasks.get_task`):
a task's settings are frozen under its version, so a results table must name it.
"""

from __future__ import annotations

from functools import partial
from typing import Any

from fxc_env.config.tasks import NAMESPACE, TASKS, get_task

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
        for task in TASKS.values():  # the task's frozen settings; keyword arguments given to make() override them
            if task.full_id not in registry:
                pettingzoo.register(env_type, task.full_id, entry_point=entry_point, kwargs=task.kwargs())
            unversioned = f"{NAMESPACE}/{task.name}"  # an exact entry: PettingZoo looks it up before resolving
            if unversioned not in registry:
                pettingzoo.register(env_type, unversioned, entry_point=partial(refuse_unversioned, unversioned))


def refuse_unversioned(task_id: str, **kwargs: Any) -> Any:
    """The entry point of ``"fxc/<task>"`` without a version: raises :func:`get_task`'s error naming ``id``."""
    return get_task(task_id, argument="id")  # raises: a versioned name is in TASKS, never this one
