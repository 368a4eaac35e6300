"""The environment as a TorchRL-native batched environment: every episode steps where its tensors live.

:class:`ConsensusTorchEnv` is a TorchRL ``EnvBase`` over the batched engine
(:class:`fxc_env.engine.ConsensusEngine`) on torch tensors: ``batch_size=[B]``, all N agents
in one group ``"agents"``, no host-device copy per step. The paper's controller for it
is :func:`fxc_env.policies.torchrl_reference.reference_policy`:
``env.rollout(K, reference_policy(env))`` plays the paper's example. Needs
``pip install "fxc-env[torchrl]"``.
"""

from __future__ import annotations

import inspect
from typing import Any, Unpack

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from fxc_env.config import EnvConfig, make_config
from fxc_env.config.arguments import (
    ARGUMENTS,
    ENV_ARGUMENTS,
    GRAPH_TENSORS,
    Argument,
    EnvKwargs,
    env_arguments,
    env_signature,
    with_arguments_table,
)
from fxc_env.config.layout import CLOCK_SIZE
from fxc_env.core import validation
from fxc_env.engine import ConsensusEngine
from fxc_env.engine.backend import torch_seed
from fxc_env.engine.graph_tensors import GRAPH_TENSOR_KEYS, edge_capacity, edge_feature_size, graph_tensors
from fxc_env.envs.episode_view import SnapshotView
from fxc_env.envs.rendering import GRID_EPISODES
from fxc_env.envs.spaces import observation_bounds

#: The one agent group of the TensorDicts.
GROUP = "agents"

#: The batched environment's own arguments, before the environment's (:mod:`fxc_env.config.arguments`).
TORCH_ARGUMENTS: tuple[Argument, ...] = (
    Argument(
        "batch_size",
        "int | tuple[int, ...] | list[int] | torch.Size",
        1,
        help="B, the number of episodes",
        card="B, the number of episodes (an int or ``[B]``)",
        card_type="``int \\| [B]``",
    ),
    Argument(
        "device",
        "Any",
        "cpu",
        help="torch device of every tensor",
        card='torch device of every tensor (``"cpu"``, ``"cuda"``; not ``"meta"``, which holds no values)',
        card_type="``str \\| torch.device``",
    ),
    Argument(
        "dtype",
        "str",
        "float64",
        help="the engine's arithmetic: float64 or float32",
        card='the engine\'s arithmetic; ``"float32"`` halves memory: agents still agree at ``T_s`` '
        "(``D(T_s)/D(0)`` <= 1e-6 at K = 200, often exactly 0 in float32) but the value they agree on drifts "
        "from Theorem 1's by float32 round-off, about 1e-5 relative (float64: 1e-12)",
        card_type='``"float64" \\| "float32"``',
    ),
    Argument(
        "seed",
        "int | None",
        None,
        help="seeds the device and host generators",
        card="seeds the device generator (initial states, ``u_max``, noise, dropout, switching) and the host "
        "generator of topology families",
    ),
    Argument(
        "check_values",
        "bool",
        True,
        help="read the device-side validity flags at every reset and episode end",
        card="read the device-side validity flags at every reset and at every episode end (one host read per "
        "episode; see below)",
        kind="boolean",
    ),
    Argument(
        "max_cycles",
        "int | None",
        None,
        help="truncate episodes after this many steps",
        card="truncate episodes after this many steps",
        kind="integer",
        minimum=1,
        maximum=10**9,
    ),
    Argument(
        "config",
        "EnvConfig | None",
        None,
        help="a prebuilt EnvConfig instead of the environment's arguments",
        card="a prebuilt :class:`~fxc_env.config.EnvConfig` (``make_config``'s) instead of the environment's "
        "arguments, which then stay at their defaults",
    ),
    GRAPH_TENSORS,
)

_OWN_ARGUMENTS = {argument.name: argument for argument in TORCH_ARGUMENTS}


class ConsensusTorchEnv(EnvBase):
    """Fixed-time consensus of double integrators, B episodes at once, as a TorchRL environment.

    ## Description
    The environment of :func:`fxc_env.parallel_env` (same maths, same options: topologies and
    families, schedules, modes, ``u_max``, noise, dropout, random switching), batched on a
    torch device. One step plays one sampling interval of every episode in closed form; an
    episode ends at ``T_s`` after K steps (``terminated``), or after ``max_cycles`` steps
    (``truncated``). Episodes start together and stay in lock step until a partial reset
    (TorchRL's ``"_reset"`` mask), after which each keeps its own clock.

    ## Arguments
    Every argument is keyword-only: the batch's own, then the environment's, those of
    :func:`fxc_env.parallel_env` (defaults in brackets come from the scenario when one is named).

    {arguments table}

    ## TensorDict entries
    | key | shape | meaning |
    |---|---|---|
    | ``("agents", "observation")`` | ``[B, N, obs_size]`` | each agent's local sampled observation (the parallel env's card), in ``obs_dtype`` |
    | ``("agents", "action")`` | ``[B, N, 2 dim]`` | each agent's action (``plan``, ``plan_balanced``, ``accel`` or ``residual``), bounded by ``action_bound`` |
    | ``("agents", "reward")`` | ``[B, N, 1]`` | the team reward ``log(D(t_k) + f) - log(D(t_{k+1}) + f)``, the same for every agent |
    | ``"done"``, ``"terminated"``, ``"truncated"`` | ``[B, 1]`` | the deadline ``T_s`` reached / ``max_cycles`` cut |
    | ``"state"`` | ``[B, N * 2 dim + 3]`` | with ``global_state="normalized"``: the scale-free global state (centralised critics) |
    | ``"edge_index"`` | ``[B, 2, E]`` int64 | with ``graph_tensors=True``: the coming interval's edges, row 0 the source j, row 1 the target i (i measures j), padding ``N -> N`` |
    | ``"edge_mask"`` | ``[B, E]`` bool | with ``graph_tensors=True``: True for an edge (the first ``n_edges``), False for padding |
    | ``"n_edges"`` | ``[B]`` int64 | with ``graph_tensors=True``: each episode's edge count |
    | ``"edge_attr"`` | ``[B, E, n dim]`` | with ``graph_tensors=True``: each edge's observation row ``z_j - z_i`` as agent i observes it, in ``obs_dtype`` |

    ## Graph tensors
    ``graph_tensors=True`` adds the coming interval's graph per episode as in the table above
    (docs: graph-tensors.md, "Graph tensors"). One episode's PyG graph:
    ``td["edge_index"][b, :, :td["n_edges"][b]]``.

    ## When a bad value is reported
    Shapes are checked at once. A non-finite action or result, or a step past ``T_s``, sets a
    flag per episode on the device; with ``check_values=True`` the environment raises
    :class:`fxc_env.core.validation.ArgumentError` (naming ``actions``) at the next reset or
    episode end, once. A ``"_reset"`` mask must be ``torch.bool`` of shape ``[B, 1]`` (or ``[B]``).

    ## Differentiable simulation
    With actions that require a gradient, the observations, the rewards and
    ``episode_metrics(as_tensors=True)`` are in their autograd graph, exact; a full reset starts
    new tensors, a partial reset cuts the restarted episodes' past, and :meth:`cut_graph` cuts
    every episode's history at the current instant (docs: differentiable.md, "Differentiable
    simulation").

    ## Rendering
    :meth:`render` returns the first ``min(B, 16)`` episodes' frames tiled, ``(H, W, 3)`` uint8
    (docs: video.md, "Video"). There is no render mode: each call reads the episodes off the device and
    adds them to their trails, so call it after every reset and step (TorchRL's
    ``PixelRenderTransform`` does); the step path does nothing for frames.

    ## Version history
    * v0: first release.
    """

    __doc__ = with_arguments_table(__doc__, (*TORCH_ARGUMENTS, *ENV_ARGUMENTS))

    @env_signature(before=TORCH_ARGUMENTS)
    def __init__(
        self,
        *,
        batch_size: int | tuple[int, ...] | list[int] | torch.Size = 1,
        device: Any = "cpu",
        dtype: str = "float64",
        seed: int | None = None,
        check_values: bool = True,
        max_cycles: int | None = None,
        config: EnvConfig | None = None,
        graph_tensors: bool = False,
        scenario: str | None = None,
        **kwargs: Unpack[EnvKwargs],
    ) -> None:
        arguments = env_arguments(locals(), kwargs)
        size = _batch_size(batch_size)
        seed = torch_seed("seed", seed)
        check_values = _OWN_ARGUMENTS["check_values"].check(check_values)
        self.config = make_config(**arguments) if config is None else _prebuilt(config, arguments)
        if self.config.obs_format != "flat":
            raise validation.ArgumentError(
                f"obs_format: the TorchRL environment gives flat observations ('flat'), got "
                f"{self.config.obs_format!r} (the PettingZoo env's dict observations)"
            )
        self.max_cycles = _OWN_ARGUMENTS["max_cycles"].check(max_cycles)
        self.check_values = check_values
        #: Whether every reset and step adds the current graph's edge tensors (docs: graph-tensors.md, "Graph tensors").
        self.graph_tensors = GRAPH_TENSORS.check(graph_tensors)
        engine = ConsensusEngine(self.config, size, device=device, dtype=dtype)
        if engine.device.type == "meta":
            raise validation.ArgumentError(
                "device: expected a device that holds values (cpu, cuda), got 'meta': TorchRL reads values at reset "
                "and step (shape-only checks run on ConsensusEngine(config, B, device='meta'))"
            )
        self.engine = engine
        super().__init__(device=engine.device, batch_size=torch.Size([size]), allow_done_after_reset=False)
        self._host_rng = np.random.default_rng(seed)
        self._observation_dtype = getattr(torch, self.config.obs_dtype)
        self._make_specs()
        if seed is not None:
            self.set_seed(seed)

    @property
    def n_agents(self) -> int:
        return self.config.n_agents

    def _make_specs(self) -> None:
        c, layout, device = self.config, self.config.layout, self.engine.device
        b, n = self.batch_size[0], c.n_agents

        def grouped(entries: dict[str, Any]) -> Composite:
            """``entries`` per agent, under the group key: ``[B, N, ...]`` inside ``[B]``."""
            return Composite({GROUP: Composite(entries, shape=(b, n))}, shape=(b,))

        low, high = observation_bounds(c)
        observation = Bounded(
            low=torch.as_tensor(low, dtype=self._observation_dtype, device=device).expand(b, n, layout.size),
            high=torch.as_tensor(high, dtype=self._observation_dtype, device=device).expand(b, n, layout.size),
            shape=(b, n, layout.size),
            dtype=self._observation_dtype,
            device=device,
        )
        observation_spec = grouped({"observation": observation})
        if c.global_state == "normalized":
            size = n * 2 * c.dim + CLOCK_SIZE
            observation_spec["state"] = Bounded(
                -1.0, 1.0, shape=(b, size), dtype=self._observation_dtype, device=device
            )
        if self.graph_tensors:
            observation_spec.update(self._graph_specs(device))
        self.observation_spec = observation_spec
        bound, dtype = c.action_bound, self.engine.dtype
        self.action_spec = grouped(
            {"action": Bounded(-bound, bound, shape=(b, n, c.action_size), dtype=dtype, device=device)}
        )
        self.reward_spec = grouped({"reward": Unbounded(shape=(b, n, 1), dtype=dtype, device=device)})
        flag = Categorical(n=2, shape=(b, 1), dtype=torch.bool, device=device)
        self.done_spec = Composite({"done": flag, "terminated": flag.clone(), "truncated": flag.clone()}, shape=(b,))

    def _graph_specs(self, device: Any) -> dict[str, Any]:
        """The root entries of :func:`fxc_env.engine.graph_tensors.graph_tensors`, padded to :attr:`n_edges_max`."""
        c, b = self.config, self.batch_size[0]
        e, features = self.n_edges_max, edge_feature_size(c)
        attr_bound = 1.0 if c.obs_mode == "normalized" else torch.inf
        return {
            "edge_index": Bounded(0, c.n_agents, shape=(b, 2, e), dtype=torch.int64, device=device),  # padding N
            "edge_mask": Categorical(n=2, shape=(b, e), dtype=torch.bool, device=device),
            "n_edges": Bounded(0, e, shape=(b,), dtype=torch.int64, device=device),
            "edge_attr": Bounded(
                -attr_bound, attr_bound, shape=(b, e, features), dtype=self._observation_dtype, device=device
            ),
        }

    @property
    def n_edges_max(self) -> int:
        """``E``, the padded edge count of ``"edge_index"``: the topology's largest graph, ``N slots`` for a family."""
        return edge_capacity(self.config)

    # ------------------------------------------------------------ EnvBase
    def set_seed(self, seed: int | None = None, static_seed: bool = False) -> int | None:
        """Seed the device and host generators (``seed``: None or an integer in ``[0, 2**64)``); TorchRL's next seed."""
        return super().set_seed(torch_seed("seed", seed), static_seed)

    def _set_seed(self, seed: int | None) -> None:
        self.engine.seed(seed)
        self._host_rng = np.random.default_rng(seed)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        # TorchRL passes reset's keywords on: this environment reads none (set_state, TorchRL's own, is
        # left to it), so a keyword such as options={"x0": ...} is refused rather than silently dropped.
        unknown = sorted(set(kwargs) - {"set_state"})
        if unknown:
            raise validation.ArgumentError(
                f"{unknown[0]}: ConsensusTorchEnv.reset takes no keyword options, got {unknown!r}; initial states "
                "come from position_range / velocity_range or initial_state (the parallel env's reset takes "
                "options={'x0': ..., 'v0': ...})"
            )
        if tensordict is not None:
            self._refuse_unread_entries(tensordict)
        engine = self.engine
        episodes = None
        if tensordict is not None and "_reset" in tensordict.keys():
            episodes = self._reset_mask(tensordict.get("_reset"))
            if bool(episodes.all()):
                episodes = None  # one read of a [B] flag: a full reset keeps the lock-step fast path
        if self.check_values:
            engine.raise_if_invalid()
        x0, v0, u_max, topologies = engine.draw_batch(self._host_rng)
        if topologies is not None and episodes is not None:
            keep = episodes.cpu().numpy()
            topologies = [
                new if reset else old for new, old, reset in zip(topologies, engine.topologies, keep, strict=True)
            ]
        engine.reset(x0, v0, topologies=topologies, u_max=u_max, episodes=episodes)
        self._cycles = (
            torch.zeros(self.batch_size[0], dtype=torch.int64, device=engine.device)
            if episodes is None
            else torch.where(episodes, 0, self._cycles)
        )
        false = torch.zeros(self.batch_size[0], dtype=torch.bool, device=engine.device)
        return self._output({}, false, false.clone())

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        engine = self.engine
        outcome = engine.step(engine.validate_actions(tensordict.get((GROUP, "action")), "actions"))
        b, n = self.batch_size[0], self.n_agents
        terminated = outcome.terminated
        if not isinstance(terminated, torch.Tensor):
            terminated = torch.full((b,), terminated, dtype=torch.bool, device=engine.device)
        self._cycles = self._cycles + 1
        truncated = (
            torch.zeros_like(terminated) if self.max_cycles is None else (self._cycles >= self.max_cycles) & ~terminated
        )
        if self.check_values and engine.steps is None and engine.done:
            engine.raise_if_invalid()  # the episode end: one read per episode
        return self._output({"reward": outcome.reward[:, None, None].expand(b, n, 1)}, terminated, truncated)

    def _output(self, entries: dict[str, Any], terminated: torch.Tensor, truncated: torch.Tensor) -> TensorDictBase:
        """A reset's or step's TensorDict: the observations and ``entries`` per agent, the ``(B,)`` flags as
        ``[B, 1]``, and the state and graph tensors where asked for."""
        observations = self._observations()
        out = TensorDict(
            {
                GROUP: TensorDict(
                    {"observation": observations, **entries}, batch_size=(self.batch_size[0], self.n_agents)
                ),
                "done": (terminated | truncated)[:, None],
                "terminated": terminated[:, None],
                "truncated": truncated[:, None],
            },
            batch_size=self.batch_size,
            device=self.engine.device,
        )
        self._add_state(out, observations)
        return out

    # ------------------------------------------------------------ helpers
    def _refuse_unread_entries(self, tensordict: TensorDictBase) -> None:
        """A reset TensorDict's root entries: ``"_reset"``, this env's own (a step's output), ``"next"``,
        ``"collector"``; any other (``"X0"``, an intended initial state) is refused, never silently dropped."""
        specs = (self.full_observation_spec, self.full_done_spec, self.full_reward_spec, self.full_action_spec)
        known = {"_reset", "next", "collector"}.union(*(spec.keys() for spec in (*specs, self.full_state_spec)))
        unknown = sorted(str(key) for key in tensordict.keys() if key not in known)
        if unknown:
            raise validation.ArgumentError(
                f"tensordict: ConsensusTorchEnv.reset reads only its '_reset' mask, got unknown key(s) {unknown!r} "
                "beside the env's own entries; initial states come from position_range / velocity_range or "
                "initial_state (the parallel env's reset takes options={'x0': ..., 'v0': ...})"
            )

    def _reset_mask(self, mask: Any) -> torch.Tensor:
        """TorchRL's ``"_reset"`` entry as a ``(B,)`` boolean mask, checked before anything changes."""
        b = self.batch_size[0]
        if not isinstance(mask, torch.Tensor) or mask.dtype != torch.bool or tuple(mask.shape) not in ((b, 1), (b,)):
            got = (
                f"dtype {mask.dtype}, shape {tuple(mask.shape)}"
                if isinstance(mask, torch.Tensor)
                else type(mask).__name__
            )
            raise validation.ArgumentError(
                f"_reset: expected a torch.bool mask of shape ({b}, 1) (or ({b},)), one entry per episode, got {got}"
            )
        return mask.reshape(-1).to(self.engine.device)

    def _observations(self) -> torch.Tensor:
        return self.engine.observations().to(self._observation_dtype)

    def _add_state(self, out: TensorDictBase, observations: torch.Tensor) -> None:
        if self.config.global_state == "normalized":
            out.set("state", self.engine.normalized_state().to(self._observation_dtype))
        if self.graph_tensors:
            tensors = graph_tensors(self.engine, observations, self.n_edges_max)
            for key, value in zip(GRAPH_TENSOR_KEYS, tensors, strict=True):
                out.set(key, value)

    def episode_metrics(self, as_tensors: bool = False) -> dict[str, Any]:
        """Every episode's metrics so far: ``(B,)`` numpy arrays (a read off the device: call at episode ends).

        ``as_tensors=True``: only the metrics that depend on the actions (``relative_deadline_error``,
        ``energy``, ``peak_input``, the final spreads, the achieved final values, ``saturated_fraction``),
        as ``(B,)`` tensors on the device in the actions' autograd graph (no read off the device), for a
        loss to backpropagate (docs: differentiable.md, "Differentiable simulation").
        """
        if not isinstance(as_tensors, bool | np.bool_):
            raise validation.ArgumentTypeError(f"as_tensors: expected True or False, got {as_tensors!r}")
        return self.engine.metric_tensors() if as_tensors else self.engine.batch_metrics()

    def cut_graph(self) -> None:
        """Go on from the same episodes with no autograd history: a later ``backward()`` stops here.

        For truncated backpropagation, or before backpropagating after a partial reset (the
        episodes that go on keep their history until then). Detach the TensorDict the next
        actions are computed from too (``td = td.detach()``). A full reset needs neither.
        """
        self.engine.cut_graph()

    def render(self) -> np.ndarray:
        """The first ``min(B, 16)`` episodes at their current instants, tiled: ``(H, W, 3)`` uint8 (docs: video.md, "Video").

        Each call reads them off the device and adds them to their trails
        (:class:`~fxc_env.envs.episode_view.SnapshotView`), so calling it after every reset and step,
        as ``torchrl.record.PixelRenderTransform`` does, draws the trails; nothing is recorded on
        the step path. Raises ``RuntimeError`` before the first reset.
        """
        if not hasattr(self, "_cycles"):
            raise RuntimeError("render: there is no episode to draw yet; call reset() first")
        view = self.__dict__.get("_snapshots")
        if view is None:
            view = self._snapshots = SnapshotView(self.config, min(self.batch_size[0], GRID_EPISODES))
        return view.grid(self.engine)


# TorchRL's metaclass and EnvBase.__new__ take (*args, **kwargs); the class's signature is
# __init__'s, so help(), inspect and IDEs list every argument as for the PettingZoo env.
_INIT_SIGNATURE = inspect.signature(ConsensusTorchEnv.__init__)
ConsensusTorchEnv.__signature__ = _INIT_SIGNATURE.replace(  # type: ignore[attr-defined]
    parameters=list(_INIT_SIGNATURE.parameters.values())[1:]
)


def _prebuilt(config: Any, arguments: dict[str, Any]) -> EnvConfig:
    """``config`` when it is an :class:`EnvConfig` and no environment argument is given beside it."""
    if not isinstance(config, EnvConfig):
        raise validation.ArgumentTypeError(
            f"config: expected an EnvConfig (make_config's), got {type(config).__name__}"
        )
    given = [
        name
        for name, value in arguments.items()
        if name not in ARGUMENTS or not _is_default(value, ARGUMENTS[name].default)
    ]
    if given:
        raise validation.ArgumentError(
            f"config: give a prebuilt config or the environment's arguments, not both (got {', '.join(given)})"
        )
    return config


def _is_default(value: Any, default: Any) -> bool:
    return value is default or (
        type(value) is type(default) and isinstance(value, str | int | float | bool) and value == default
    )


def _batch_size(value: Any) -> int:
    if isinstance(value, tuple | list | torch.Size):
        if len(value) != 1:
            raise validation.ArgumentError(f"batch_size: expected an int or a one-element size [B], got {list(value)}")
        value = value[0]
    return validation.integer("batch_size", value, 1, validation.MAX_AGENTS)
