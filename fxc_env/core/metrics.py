"""Disagreement measures and per-episode metrics (SPEC 4.4 and 5).

``e_x = max_ij ||x_i - x_j||_2`` (the diameter of the agents' positions), ``e_v`` likewise,
and the disagreement ``D = e_x + T_s e_v`` (metres), which weighs a velocity mismatch by
how far it would carry an agent over the whole horizon. Arrays are ``(..., N, dim)``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

#: Thresholds of the settling-time metric ``t_eps`` (SPEC 5).
SETTLING_THRESHOLDS = (1e-2, 1e-6)

_PAIRWISE_CHUNK = 256


def spread(z: np.ndarray) -> np.ndarray:
    """Diameter ``max_ij ||z_i - z_j||_2`` over the agent axis (-2); shape ``(...)``.

    Exact. O(N) for ``dim = 1``; for ``dim > 1`` pairwise in chunks, O(N^2 dim).
    """
    if z.shape[-1] == 1:
        return np.max(z[..., 0], axis=-1) - np.min(z[..., 0], axis=-1)
    n = z.shape[-2]
    best = np.zeros(z.shape[:-2])
    # Measure from the centroid first: distances are small differences there.
    z = z - z.mean(axis=-2, keepdims=True)
    for start in range(0, n, _PAIRWISE_CHUNK):
        block = z[..., start : start + _PAIRWISE_CHUNK, :]
        diff = block[..., :, None, :] - z[..., None, :, :]
        best = np.maximum(best, np.sqrt(np.max(np.sum(diff * diff, axis=-1), axis=(-2, -1))))
    return best


def disagreement(x: np.ndarray, v: np.ndarray, settling_time: float) -> np.ndarray:
    """``D = e_x + T_s e_v`` in metres, shape ``(...)``."""
    return spread(x) + settling_time * spread(v)


def reward_floor(initial_disagreement: np.ndarray, relative_floor: float) -> np.ndarray:
    """Floor ``f`` of the log-reward: ``relative_floor * D(0)``, or 1 where ``D(0) = 0``."""
    return np.where(initial_disagreement > 0, relative_floor * initial_disagreement, 1.0)


@dataclass(frozen=True)
class EpisodeMetrics:
    """SPEC 5's per-episode figures. Lengths in metres, times in seconds.

    ``t_eps_*`` is the first sampling instant from which ``D(t_k) / D(0) < eps`` at every
    later sampling instant (``inf`` if that never happens by ``T_s``).
    ``predicted_*`` come from Theorems 1-2 (``xi``) and are NaN where they do not apply
    (random switching) or ``xi`` is not computed (very large N); ``achieved_*`` are the
    agents' means at the end. ``saturated_fraction`` is the share of agent-time spent at
    the input limit ``u_max`` (mean over components; 0 without a limit).
    For ``dim > 1`` the predicted and achieved values are the first component.
    """

    final_position_spread: float
    final_velocity_spread: float
    relative_deadline_error: float
    t_eps_1e_2: float
    t_eps_1e_6: float
    energy: float
    peak_input: float
    sampling_instants: int
    predicted_final_position: float
    achieved_final_position: float
    predicted_final_velocity: float
    achieved_final_velocity: float
    saturated_fraction: float

    def as_dict(self) -> dict[str, float | int | None]:
        """Plain dict for JSON (non-finite values become ``None``)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}


def metrics_rows(columns: dict[str, np.ndarray]) -> list[dict[str, float | int | None]]:
    """Per-episode dicts (as :meth:`EpisodeMetrics.as_dict`) from ``(B,)`` metric columns."""
    names = [f.name for f in fields(EpisodeMetrics)]
    values = []
    for name in names:
        column = columns[name]
        if column.dtype.kind == "f":
            objects = column.astype(object)
            objects[~np.isfinite(column)] = None
            values.append(objects.tolist())
        else:
            values.append(column.tolist())
    return [dict(zip(names, row, strict=True)) for row in zip(*values, strict=True)]
