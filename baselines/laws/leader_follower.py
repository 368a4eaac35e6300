"""A time-optimal law for a known graph: follow the centre, exact after exactly the radius.

Law, source, proven graph class and refusals: docs: optimality.md, "Follow the centre (`leader_follower`)".
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.baselines.laws.minimum_time import refuse_what_a_graph_design_cannot_honour
from fxc_env.baselines.laws.motion_signals import plan_action
from fxc_env.baselines.laws.policy import LawPolicy, lost_link_guarantee
from fxc_env.config import config_of
from fxc_env.core.graphs import Topology
from fxc_env.core.optimality import radius_centre, reach_intervals
from fxc_env.core.validation import ArgumentError


def follower_slots(topology: Topology, centre: int) -> np.ndarray:
    """The observation row each agent follows on each interval, ``(R + 1, N)`` int; -1: coast.

    Row k (``k < R``, R the centre's reach time) holds, per agent, the slot of its parent among its
    in-neighbours of ``G_{k mod m}``: with ``s(r) = 0``, an agent with ``s(i) > k`` follows its in-neighbour
    with the smallest ``s(j)`` (ties: the smaller index), synchronised at ``t_{k+1}`` when ``s(j) <= k``; a
    synchronised agent, or one with no in-neighbour, coasts. Row R, used from interval R on, is all -1.
    """
    n, m = topology.n_agents, topology.period
    index, mask = topology.neighbour_index, topology.neighbour_mask  # (m, N, d_max)
    synced = np.full(n, np.iinfo(np.int64).max, dtype=np.int64)  # s(i): the instant i joins the centre
    synced[centre] = 0
    rows = []
    k = 0
    while np.any(synced > k):
        g = k % m
        s_of_neighbour = np.where(mask[g], synced[index[g]], np.iinfo(np.int64).max)  # (N, d_max)
        slot = np.argmin(s_of_neighbour, axis=1) if index.shape[2] else np.zeros(n, dtype=np.int64)
        best = s_of_neighbour[np.arange(n), slot] if index.shape[2] else np.full(n, np.iinfo(np.int64).max)
        follows = (synced > k) & (best < np.iinfo(np.int64).max)
        rows.append(np.where(follows, slot, -1))
        synced = np.where((synced > k) & (best <= k), k + 1, synced)
        k += 1
        if k > m * n:
            raise AssertionError("the joint graph spans, so the centre reaches every agent within m N intervals")
    rows.append(np.full(n, -1, dtype=np.int64))
    return np.stack(rows).astype(np.int64)


class LeaderFollowerPolicy(LawPolicy):
    """The leader-follower law on the local observation, every ``action_mode`` and ``obs_mode``.

    Args:
        env: an fxc_env environment or an :class:`~fxc_env.EnvConfig` on a fixed digraph or a periodic
            switching topology, ideal double-integrator agents (any schedule, ``dim``, modes).
        centre: the leader (an agent index); default: an agent attaining the radius
            (:func:`fxc_env.core.optimality.radius_centre`). Another root is allowed and is exact
            after its own reach time.
        allow_dropout: run under ``link_dropout`` too (off by default: :attr:`LOST_LINK` says what a lost link
            costs; docs: optimality.md, "Lost links").

    Raises:
        ArgumentError naming ``topology``, ``switching``, ``u_max``, ``obs_noise``, ``link_dropout``,
        ``agent_model`` or ``centre`` for what the design cannot honour.
    """

    NAME: ClassVar[str] = "leader_follower"
    LAW: ClassVar[str] = (
        "the centre coasts; every other agent plans z_i(t_k+1) = P_k z_p(t_k) (its parent's coasted state, "
        "from its own row of p) in a time-respecting shortest-path tree from the centre"
    )
    SOURCE: ClassVar[str] = "this project (leader-follower dead-beat copy on an offline shortest-path tree)"
    GRAPH_CLASS: ClassVar[str] = (
        "fixed digraph with a directed spanning tree or a spanning periodic switching, ideal agents: exact after "
        "the radius"
    )

    #: Each agent follows its own row of the tree, found by its place in the team: one agent's observation alone
    #: is refused (:mod:`fxc_env.policies.protocol`).
    needs_team: ClassVar[bool] = True

    #: What one lost link costs the law (the refusal of ``link_dropout`` and :meth:`guarantee` say it).
    LOST_LINK: ClassVar[str] = (
        "an agent whose row of its parent is lost on its last copy coasts off the centre's trajectory and takes "
        "every agent that follows it along: worst D(T_s)/D(0) of 20 seeds on a ring of 20, 1.2 at p = 1e-3, "
        "1.8 at 1e-2"
    )

    def __init__(self, env: Any, centre: int | None = None, allow_dropout: bool = False) -> None:
        config = config_of(env, type(self).__name__)
        refuse_what_a_graph_design_cannot_honour(
            config, type(self).__name__, periods=True, allow_dropout=allow_dropout, lost_link=self.LOST_LINK
        )
        topology = config.topology
        roots, reach = reach_intervals(topology)
        if centre is None:
            centre = radius_centre(topology)
        elif isinstance(centre, bool) or not isinstance(centre, (int, np.integer)) or int(centre) not in roots:
            raise ArgumentError(
                f"centre: expected a root of the graph (an agent that reaches every agent), one of {roots.tolist()}, "
                f"got {centre!r}"
            )
        self.config = config
        self.layout = config.layout
        #: The leader, and the intervals after which every agent is on its coasted trajectory.
        self.centre = int(centre)
        self.needed_intervals = int(reach[np.flatnonzero(roots == self.centre)[0]])
        #: ``(needed_intervals + 1, N)``: the row each agent follows per interval (-1: coast).
        self.slots = follower_slots(topology, self.centre)
        self._intervals = np.asarray(config.schedule.intervals, dtype=np.float64)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Plans (``plan`` mode) or end inputs (``accel``) from every agent's flat observation ``(..., N, obs_size)``."""
        c = self.config
        obs = np.asarray(obs, dtype=np.float64)
        if obs.ndim < 2 or obs.shape[-2] != c.n_agents:
            raise ArgumentError(
                f"observation: the leader-follower law follows a per-agent tree and needs every agent's observation "
                f"at once, shape (..., {c.n_agents}, {self.layout.size}); got {obs.shape}"
            )
        rows, _, clock = self.layout.split(obs)  # rows (..., N, slots, 2, dim)
        k = np.clip(np.rint(clock[..., 2] * c.n_intervals).astype(np.int64), 0, c.n_intervals - 1)  # (..., N)
        slot = self.slots[np.minimum(k, len(self.slots) - 1), np.arange(c.n_agents)]  # (..., N)
        chosen = np.take_along_axis(rows, np.maximum(slot, 0)[..., None, None, None], axis=-3)[..., 0, :, :]
        follow = (slot >= 0)[..., None]
        dx, dv = chosen[..., 0, :] * follow, chosen[..., 1, :] * follow  # (..., N, dim); 0 for coasting
        # Raw rows: a_x = dx + T_k dv, a_v = dv. Normalized rows dx/s, T_k dv/s and plans a_x/s, T_k a_v/s:
        # alpha_x = rho_x + rho_v, alpha_v = rho_v.
        interval = 1.0 if c.obs_mode == "normalized" else self._intervals[k][..., None]
        return plan_action(np.stack([dx + interval * dv, dv], axis=-2), c, interval)

    def parameters(self) -> dict[str, float]:
        """The design: the centre and the intervals after which the law is exact."""
        return {"centre": float(self.centre), "needed_intervals": float(self.needed_intervals)}

    def guarantee(self) -> str:
        if self.config.n_intervals < self.needed_intervals:
            return (
                f"no exact guarantee: K = {self.config.n_intervals} < {self.needed_intervals} intervals (the radius "
                "from the centre)"
            )
        exact = f"exact in exact arithmetic after {self.needed_intervals} intervals, the radius (round-off aside)"
        # Every agent but the centre needs its last copy (the one that lands it on the centre's trajectory).
        return lost_link_guarantee(self.config, exact, self.config.n_agents - 1, self.LOST_LINK)
