"""The environment as a BenchMARL task: every named scenario and versioned task, run by BenchMARL's algorithms.

:class:`FxcTask` is a BenchMARL task enum (one member per scenario of
:data:`fxc_env.config.scenarios.SCENARIOS`, ``fxc/<scenario>``, and one per named task of
:data:`fxc_env.config.tasks.TASKS`, ``fxc/<task>-v<k>``) and :class:`FxcTaskClass` the task it
builds: a factory of :class:`fxc_env.envs.torch_env.ConsensusTorchEnv` (``batch_size`` =
BenchMARL's number of environments), one agent group ``"agents"``, continuous actions only.
A task's config is a dict of ``ConsensusTorchEnv`` keyword arguments, checked when the task is
made; BenchMARL owns ``batch_size``, ``seed`` and ``device`` and a config naming one is refused.
:func:`register` puts the tasks in BenchMARL's registry and Hydra's ``task`` group (``python -m
fxc_env.envs.benchmarl_run`` calls it before BenchMARL's own command line). Use, the plugin and an experiment: docs:
tutorials/benchmarl.md, "Tutorial: BenchMARL".

Needs ``pip install "fxc-env[benchmarl]"`` (BenchMARL 1.5 with torchrl 0.11); ``import fxc_env``
never imports this module.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from importlib import resources
from typing import Any

import yaml

try:
    from benchmarl.environments.common import Task, TaskClass
except ModuleNotFoundError as error:
    raise ModuleNotFoundError(
        'fxc_env.envs.benchmarl_task needs BenchMARL: pip install "fxc-env[benchmarl]" (docs: tutorials/benchmarl.md, "Tutorial: BenchMARL")',
        name=error.name,
    ) from error
import torch
from torchrl.data import Composite
from torchrl.envs import DTypeCastTransform, EnvBase

from fxc_env.config.scenarios import SCENARIOS
from fxc_env.config.tasks import TASKS
from fxc_env.core import validation
from fxc_env.envs.torch_env import GROUP, ConsensusTorchEnv

#: The environment's name in BenchMARL (its results, folders and ``"fxc/<task>"`` names).
ENV_NAME = "fxc"

#: The ConsensusTorchEnv arguments that BenchMARL's experiment sets, never a task's config.
BENCHMARL_OWNED = {
    "batch_size": "the experiment config's on_policy_n_envs_per_worker / off_policy_n_envs_per_worker "
    "/ evaluation_episodes",
    "seed": "the Experiment's seed",
    "device": "the experiment config's sampling_device",
}

#: The package folder of the default task configs, one ``<scenario>.yaml`` each.
CONFIG_FOLDER = "benchmarl_tasks"

#: What BenchMARL adds to a named task's frozen settings (its networks are float32; the engine still
#: computes in float64; the scale-free global state is the centralised critics' ``"state"``).
BENCHMARL_SETTINGS = {"obs_dtype": "float32", "global_state": "normalized"}


class FxcTaskClass(TaskClass):
    """One fxc_env scenario as a BenchMARL task (``name``: the enum member's name; ``config``: env arguments).

    The config is checked at once (names, then values, by a one-episode
    :class:`~fxc_env.envs.torch_env.ConsensusTorchEnv`); bad ones raise
    :class:`fxc_env.core.validation.ArgumentError` naming the argument.
    """

    def __init__(self, name: str, config: dict[str, Any] | None) -> None:
        config = {} if config is None else dict(config)
        _check_config(config)
        super().__init__(name=name, config=config)
        self._make_env(num_envs=1, seed=None, device="cpu")  # the environment's own checks of every value

    def _make_env(self, num_envs: int, seed: int | None, device: Any) -> ConsensusTorchEnv:
        return ConsensusTorchEnv(batch_size=num_envs, seed=seed, device=device, **copy.deepcopy(self.config))

    # ------------------------------------------------------------ the environment
    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        """A factory of ``ConsensusTorchEnv(batch_size=num_envs, seed=seed, device=device, **config)``."""
        if not continuous_actions:
            raise validation.ArgumentError(
                "continuous_actions: fxc_env's actions are continuous (plans or inputs), got False "
                "(choose an algorithm with continuous actions, or prefer_continuous_actions=True)"
            )
        return lambda: self._make_env(num_envs=num_envs, seed=seed, device=device)

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def get_env_transforms(self, env: EnvBase) -> list[Any]:
        """BenchMARL's networks and losses are float32: with the float64 engine, the actions they give are cast
        up to the engine's float64 and the rewards down to float32 (Q critics such as MASAC's and MADDPG's read
        the action beside the float32 observation; the engine still computes in float64)."""
        if _base(env).engine.dtype != torch.float64:
            return []
        return [
            DTypeCastTransform(
                torch.float64, torch.float32, in_keys=[(GROUP, "reward")], in_keys_inv=[(GROUP, "action")]
            )
        ]

    def has_render(self, env: EnvBase) -> bool:
        """False: BenchMARL's default ``render: True`` would write its evaluation videos through
        torchvision, which has no CPU build for the torch on which this extra is tested; frames
        come from ``ConsensusTorchEnv.render`` and ``fxc simulate --video`` (docs: video.md, "Video")."""
        return False

    def max_steps(self, env: EnvBase) -> int:
        """The steps of an evaluation episode: K sampling intervals, or ``max_cycles`` when shorter."""
        return _episode_steps(_base(env))

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        """One group, ``"agents"``: ``agent_0 .. agent_{N-1}`` (the PettingZoo env's names)."""
        return {GROUP: [f"agent_{i}" for i in range(_base(env).n_agents)]}

    # ------------------------------------------------------------ specs (unbatched: BenchMARL's convention)
    def observation_spec(self, env: EnvBase) -> Composite:
        """The group's entries only: ``("agents", "observation")`` of shape ``[N, obs_size]``."""
        return Composite({GROUP: env.full_observation_spec_unbatched[GROUP].clone()})

    def state_spec(self, env: EnvBase) -> Composite | None:
        """``"state"`` ``[N * 2 dim + 3]`` with ``global_state="normalized"``, else None."""
        spec = env.full_observation_spec_unbatched
        return Composite({"state": spec["state"].clone()}) if "state" in spec.keys() else None

    def info_spec(self, env: EnvBase) -> Composite | None:
        return None  # the episode metrics are read with ConsensusTorchEnv.episode_metrics()

    def action_spec(self, env: EnvBase) -> Composite:
        """``("agents", "action")`` of shape ``[N, 2 dim]`` (``action_size``), within ``action_bound``."""
        return env.full_action_spec_unbatched

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    @staticmethod
    def env_name() -> str:
        return ENV_NAME


class _FxcTasks(Task):
    """fxc_env's scenarios as BenchMARL tasks; ``FxcTask.PAPER_FIG1.get_from_yaml()`` gives the task.

    ``get_from_yaml()`` reads the shipped ``fxc_env/envs/benchmarl_tasks/<scenario>.yaml``
    (``get_from_yaml(path)`` another file), ``get_task(config)`` takes a dict.
    """

    @staticmethod
    def associated_class() -> type[FxcTaskClass]:
        return FxcTaskClass

    @property
    def task_name(self) -> str:
        """The name after ``fxc/`` in BenchMARL: the scenario, or the versioned task's id (``rings20-v1``)."""
        head, _, version = self.name.lower().rpartition("_v")
        return f"{head}-v{version}" if head and version.isdigit() else self.name.lower()

    def default_config(self) -> dict[str, Any]:
        """The shipped config: a named task's frozen settings with :data:`BENCHMARL_SETTINGS`, or the
        scenario's ``fxc_env/envs/benchmarl_tasks/<scenario>.yaml``."""
        if self.task_name in TASKS:
            return {**TASKS[self.task_name].kwargs(), **BENCHMARL_SETTINGS}
        text = resources.files("fxc_env.envs").joinpath(CONFIG_FOLDER, f"{self.task_name}.yaml").read_text()
        return yaml.safe_load(text)

    def get_from_yaml(self, path: str | None = None) -> FxcTaskClass:
        """The task with the config in ``path`` (a YAML mapping of env arguments), by default the shipped one."""
        if path is None:
            return self.get_task(config=self.default_config())
        with open(path, encoding="utf-8") as file:
            config = yaml.safe_load(file.read())
        if config is None:
            config = {}
        if not isinstance(config, dict):
            raise validation.ArgumentError(
                f"path: expected a YAML mapping of ConsensusTorchEnv arguments, got a {type(config).__name__} in {path}"
            )
        return self.get_task(config=config)


#: One member per scenario of :data:`~fxc_env.config.scenarios.SCENARIOS` (``PAPER_FIG1``, ``RING_6``, ...), then per
#: named task of :data:`~fxc_env.config.tasks.TASKS` (``RINGS20_V1``; v2: the same settings at K = 50 with
#: ``action_mode="plan_balanced"``, docs: tasks/index.md, "Named tasks"): the name upper-cased, ``-`` as ``_``.
FxcTask = _FxcTasks(
    "FxcTask",
    [(name.replace("-", "_").upper(), None) for name in (*SCENARIOS, *TASKS)],
    module=__name__,
    qualname="FxcTask",
)


def register() -> None:
    """Make every member known to BenchMARL's command line and ``load_task_config_from_hydra`` (idempotent).

    BenchMARL's docs ask an external task for two things: an entry ``"fxc/<task>"`` in
    ``benchmarl.environments.task_config_registry``, and its config in Hydra's ``task`` group
    (here Hydra's config store, from :meth:`FxcTask.default_config`, instead of files in
    BenchMARL's ``conf/task``). ``python -m fxc_env.envs.benchmarl_run`` calls this before
    BenchMARL's ``hydra_experiment``; call it yourself before your own
    ``hydra.main`` or ``load_task_config_from_hydra``.
    """
    from benchmarl.environments import task_config_registry
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    for member in FxcTask:
        task_config_registry[f"{ENV_NAME}/{member.task_name}"] = member
        store.store(group=f"task/{ENV_NAME}", name=member.task_name, node=member.default_config(), provider="fxc_env")


def _check_config(config: dict[str, Any]) -> None:
    """Refuse the arguments BenchMARL sets and any name ConsensusTorchEnv does not take, by name."""
    for name in config:
        if name in BENCHMARL_OWNED:
            raise validation.ArgumentError(
                f"{name}: set by BenchMARL ({BENCHMARL_OWNED[name]}), not by the task config"
            )
    accepted = set(ConsensusTorchEnv.__signature__.parameters) - set(BENCHMARL_OWNED)  # type: ignore[attr-defined]
    unknown = sorted(str(name) for name in config if name not in accepted)
    if unknown:
        raise validation.ArgumentError(
            f"{unknown[0]}: not a ConsensusTorchEnv argument (a task config takes {', '.join(sorted(accepted))})"
        )


def _base(env: EnvBase) -> ConsensusTorchEnv:
    """The ConsensusTorchEnv under BenchMARL's TransformedEnv wrappers."""
    while not isinstance(env, ConsensusTorchEnv) and hasattr(env, "base_env"):
        env = env.base_env
    if not isinstance(env, ConsensusTorchEnv):
        raise validation.ArgumentTypeError(
            f"env: expected a ConsensusTorchEnv (or one wrapped), got {type(env).__name__}"
        )
    return env


def _episode_steps(env: ConsensusTorchEnv) -> int:
    steps = env.config.n_intervals
    return steps if env.max_cycles is None else min(steps, env.max_cycles)
