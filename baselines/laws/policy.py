"""What every baseline shares: reading the local observation and holding an input.

A baseline is built from an environment (parallel, AEC, VecEnv) or an :class:`~fxc_env.EnvConfig` and maps
observations ``(..., obs_size)`` to actions ``(..., 2 dim)`` in one vectorised call. It reads only the
observation (its in-neighbours' rows ``[x_j - x_i, v_j - v_i]`` at ``t_k``, their mask, the clock) and the
environment's settings; gains the papers choose from the graph are chosen once, offline
(:mod:`fxc_env.baselines.laws.design`). The classical laws act in ``accel`` mode with a zero-order hold: the
action is ``(u, u)``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from fxc_env.config import config_of
from fxc_env.config.layout import ObservationLayout
from fxc_env.core import validation
from fxc_env.core.validation import ArgumentError
from fxc_env.policies.protocol import Policy

#: Largest gain or time constant of a classical law (``g`` in 1/s², ``γ`` in s, the finite-time gain): with
#: states within ±1e100 (:data:`~fxc_env.core.validation.STATE_LIMIT`) and up to 1e8 neighbours, a held input
#: ``g Σ_j (z_j - z_i)`` stays below 1e121 and its interval energy finite in float64; the theorems hold for
#: every positive value, and :meth:`LawPolicy.guarantee` says what holding the input over the schedule changes.
MAX_GAIN = 1e12


def law_gain(name: str, value: Any, unit: str) -> float:
    """A classical law's gain or time constant as a float, ``0 < value <= MAX_GAIN``; else an error naming ``name``."""
    return validation.in_range(
        name,
        value,
        0.0,
        MAX_GAIN,
        low_open=True,
        below=f"the law's theorem needs a positive {name} ({unit})",
        above=f"above 1e12 {unit} a held input leaves float64 for states the environment admits",
    )


def refuse_lost_links(config: Any, name: str, allow_dropout: Any, lost_link: str) -> None:
    """Refuse ``link_dropout`` unless ``allow_dropout``, saying what a lost link costs the law (``lost_link``).

    Raises:
        ArgumentError naming ``allow_dropout`` (not a bool) or ``link_dropout`` (on, not opted in).
    """
    validation.boolean("allow_dropout", allow_dropout)
    if config.link_dropout != 0 and not allow_dropout:
        raise ArgumentError(
            f"link_dropout: {name} needs every row it reads: {lost_link}; got link_dropout={config.link_dropout!r} "
            '(allow_dropout=True runs it anyway; docs: optimality.md, "Lost links")'
        )


def rows_read(config: Any, intervals: int) -> int:
    """The neighbour rows the team receives on intervals ``0 .. intervals - 1`` of the config's (periodic) graph."""
    per_graph = config.topology.neighbour_mask.reshape(config.topology.period, -1).sum(axis=1)
    return int(sum(per_graph[k % len(per_graph)] for k in range(intervals)))


def lost_link_guarantee(config: Any, exact: str, reads: int, lost_link: str) -> str:
    """A law's :meth:`guarantee`: ``exact`` without lost links; under ``link_dropout`` p (opted in) none, but the
    chance ``(1 - p)^reads`` that none of the ``reads`` rows its exactness needs is lost (then the run is exact as
    without lost links, so the share of exact seeds is at least that), and what a lost one costs (``lost_link``)."""
    p = config.link_dropout
    if p == 0:
        return exact
    return (
        f"no exact guarantee under link_dropout = {p:g} (exact wherever none of the {reads} rows it needs is lost, "
        f"probability (1 - p)^{reads} = {(1.0 - p) ** reads:.2g} per episode; {lost_link}); without lost links: "
        f"{exact}"
    )


#: The phrases with which a law's ``guarantee()`` claims exact consensus at ``T_s`` on its configuration, rounding
#: aside ("no exact guarantee", "not exact where ..." deny it). A law that claims it keeps it in any units: its
#: D(T_s)/D(0) does not depend on the scale of the initial state (tests/baselines/test_scale_free.py).
EXACT_CLAIMS = ("exact in exact arithmetic", "exact (rounding / ε aside)")


def claims_exactness(policy: Any) -> bool:
    """Whether ``policy.guarantee()`` (none: no) claims exact consensus at ``T_s`` (:data:`EXACT_CLAIMS`)."""
    guarantee = getattr(policy, "guarantee", None)
    text = guarantee() if callable(guarantee) else ""
    return any(claim in text for claim in EXACT_CLAIMS)


class LawPolicy(Policy):
    """Base class of every baseline: the law's description, called as every policy is
    (:mod:`fxc_env.policies.protocol`: the parallel env's dict, an array ``(..., N, obs_size)``, or one
    agent's observation for a law without memory).

    Subclasses set :attr:`NAME`, :attr:`LAW`, :attr:`SOURCE`, :attr:`GRAPH_CLASS` and ``self.layout``, and
    implement :meth:`act`.
    """

    #: Name used by the benchmark and :func:`baselines.load_policy`.
    NAME: ClassVar[str] = "hold"
    #: The feedback law, written out.
    LAW: ClassVar[str] = ""
    #: The paper (family) the law comes from.
    SOURCE: ClassVar[str] = ""
    #: The graphs for which the source proves convergence.
    GRAPH_CLASS: ClassVar[str] = ""
    layout: ObservationLayout

    def parameters(self) -> dict[str, float]:
        """The law's parameters as used (after any offline design)."""
        return {}

    def describe(self) -> dict[str, str]:
        """Law, source, proven graph class and parameters (``parameters()``), for tables and logs."""
        params = ", ".join(f"{k} = {v:.4g}" for k, v in self.parameters().items())
        return {
            "name": self.NAME,
            "law": self.LAW,
            "source": self.SOURCE,
            "graph_class": self.GRAPH_CLASS,
            "parameters": params,
        }


class HoldPolicy(LawPolicy):
    """Base class: a feedback law on the local observation, held over each interval (ZOH).

    Subclasses set :attr:`LAW`, :attr:`SOURCE`, :attr:`GRAPH_CLASS` and :attr:`OBS_MODES`,
    and implement :meth:`input` (the physical input ``u_i`` in m/s^2 from raw rows) or
    override :meth:`act`.
    """

    #: Observation modes the law can be computed in.
    OBS_MODES: ClassVar[tuple[str, ...]] = ("raw",)

    def __init__(self, env: Any) -> None:
        self.config = config_of(env, type(self).__name__)
        self.layout = self.config.layout
        if self.config.action_mode != "accel":
            raise ArgumentError(
                f"action_mode: {type(self).__name__} holds an input (zero-order hold) and needs "
                f"action_mode='accel', got {self.config.action_mode!r}"
            )
        if self.config.obs_mode not in self.OBS_MODES:
            raise ArgumentError(
                f"obs_mode: {type(self).__name__} supports {self.OBS_MODES}, got {self.config.obs_mode!r}"
            )

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Zero-order hold of :meth:`input`: the action ``(u, u)``, ``(..., 2 dim)``."""
        rows, mask, clock = self.layout.split(obs)
        u = self.input(rows[..., 0, :], rows[..., 1, :], mask, clock)
        return np.concatenate([u, u], axis=-1)

    def input(self, dx: np.ndarray, dv: np.ndarray, mask: np.ndarray, clock: np.ndarray) -> np.ndarray:
        """Physical input ``u_i`` ``(..., dim)`` from rows ``x_j - x_i``, ``v_j - v_i`` ``(..., d_max, dim)``."""
        raise NotImplementedError

    def time_features(self, clock: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``t_k`` and ``T_{k+1}`` in seconds from the clock, each ``(..., 1)``."""
        settling_time = self.config.settling_time
        return clock[..., 0:1] * settling_time, clock[..., 1:2] * settling_time


class LinearRowPolicy(HoldPolicy):
    """A law linear in the rows: ``u_i = sum_j a_ij [p (x_j - x_i) + q (v_j - v_i)]``.

    ``p`` (1/s^2) and ``q`` (1/s) may depend on the clock (:meth:`row_gains`). On normalized rows the action
    is ``alpha = T^2 sum_j [p dx_j + (q / T) dv_j]`` (homogeneous of degree one: ``s_i`` is never needed).
    """

    OBS_MODES: ClassVar[tuple[str, ...]] = ("raw", "normalized")

    def row_gains(self, clock: np.ndarray) -> tuple[np.ndarray | float, np.ndarray | float]:
        """``(p, q)``: the position gain (1/s^2) and velocity gain (1/s), broadcastable to ``(..., 1)``."""
        raise NotImplementedError

    def act(self, obs: np.ndarray) -> np.ndarray:
        rows, mask, clock = self.layout.split(obs)
        real = mask[..., None]  # a_ij: 1 on an in-neighbour's row, 0 on padding
        sum_dx = np.sum(real * rows[..., 0, :], axis=-2)
        sum_dv = np.sum(real * rows[..., 1, :], axis=-2)
        p, q = self.row_gains(clock)
        if self.config.obs_mode == "normalized":
            _, T = self.time_features(clock)
            u = (T * T) * (p * sum_dx + (q / T) * sum_dv)
        else:
            u = p * sum_dx + q * sum_dv
        return np.concatenate([u, u], axis=-1)
