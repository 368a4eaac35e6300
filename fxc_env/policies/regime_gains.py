"""Two learned gain schedules and a memory that picks one: fixed graph or switching, told by the agent itself.

:class:`RegimeGainPolicy` is the network of the shipped ``agnostic`` policy (docs: results.md,
"agnostic policy"). Every agent plans ``G_k r_i`` from its own aggregated relative row ``r_i``, as
:class:`~fxc_env.policies.interval_gains.IntervalGainPolicy` does, from one of two learned
``(K, 2, 2)`` tables: ``gains`` (a fixed graph) or ``switching_gains`` (the graph changes between
intervals). Which one, the agent finds out from its own memory:

For the first ``probes`` intervals both tables are zero and every agent coasts; an agent whose
mask changes or whose rows are not the coasted rows (relative tolerance :data:`TOLERANCE`) has
seen its in-neighbour set change and uses ``switching_gains`` for the rest of the episode. The
policy is called with every agent's observation at once, ``(..., N, obs_size)``, one instant
after the other (a call that skips or repeats an instant is refused by name); any ``dim``.
The probe and the memory: docs: training.md, "The agnostic policy's probe".

**File format** (``.npz``, read with ``allow_pickle=False``): ``gains`` and ``switching_gains``
``(K, 2, 2)`` float64, and ``header`` as a gain schedule's
(:mod:`fxc_env.policies.interval_gains`) with ``format`` :data:`REGIME_FORMAT` and ``probes``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fxc_env.core.validation import ArgumentError
from fxc_env.policies.interval_gains import FORMAT_READERS, MATCHED_SETTINGS, REGIME_FORMAT, IntervalGainPolicy

__all__ = ["REGIME_FORMAT", "TOLERANCE", "RegimeGainPolicy", "read_regime_gains"]
#: Rows that differ from the coasted rows by more than this (relative to their largest entry) have changed.
TOLERANCE = 1e-9


class RegimeGainPolicy(IntervalGainPolicy):
    """``G_k r_i`` from the fixed-graph or the switching table, chosen per agent by its own probe (see the module).

    Args:
        gains: ``(K, 2, 2)`` the fixed-graph table, normalized units, float64.
        switching_gains: ``(K, 2, 2)`` the switching table.
        header: the file's header; ``env`` holds the training settings, ``probes`` the coasting intervals.
        source: where it was read from, for messages.
    """

    #: Its probe remembers every agent's previous rows: one agent's observation alone is refused
    #: (:mod:`fxc_env.policies.protocol`).
    needs_team = True
    #: The table is linear in the rows: ``dim`` is not matched (every axis is planned alike, exactly).
    matched_settings = {key: value for key, value in MATCHED_SETTINGS.items() if key != "dim"}

    def __init__(
        self,
        gains: np.ndarray,
        switching_gains: np.ndarray,
        header: Mapping[str, Any],
        source: str | Path | None = None,
    ) -> None:
        super().__init__(gains, header, source)
        switching = np.asarray(switching_gains, dtype=np.float64)
        if switching.shape != self.gains.shape or not np.all(np.isfinite(switching)):
            raise ArgumentError(
                f"switching_gains: expected a finite table of the gains' shape {self.gains.shape}, got {switching.shape}"
            )
        probes = header.get("probes")
        if not isinstance(probes, int) or not 1 <= probes < len(switching):
            raise ArgumentError(f"probes: expected an integer in [1, K), got {probes!r}")
        if np.any(self.gains[:probes]) or np.any(switching[:probes]):
            raise ArgumentError(f"gains: both tables must be zero on the first probes = {probes} intervals (the probe)")
        self.switching_gains = switching
        self.probes = probes
        self._memory: dict[str, np.ndarray] | None = None

    @property
    def switched(self) -> np.ndarray | None:
        """Per agent of the episodes under way, whether its probe saw its graph change ``(..., N)`` (None before a call)."""
        return None if self._memory is None else self._memory["switched"].copy()

    def reset(self) -> None:
        """Forget every episode under way (the next call must be at ``k = 0``)."""
        self._memory = None

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Plans ``(..., 2 dim)`` for every agent's flat observation ``(..., N, obs_size)`` at one instant (see the module)."""
        rows, mask, clock, k, r = self._read(obs)
        switched = self._remember(rows, mask > 0.5, clock[..., 1], k)
        gains = np.where(switched[..., None, None], self.switching_gains[k], self.gains[k])
        plan = gains @ r  # (..., 2, dim)
        return np.concatenate([plan[..., 0, :], plan[..., 1, :]], axis=-1)

    def _remember(self, rows: np.ndarray, mask: np.ndarray, interval: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Update each agent's memory with this instant's rows; return whether it has seen its graph change."""
        start = k == 0
        memory = self._memory
        if memory is None or memory["k"].shape != k.shape:
            if not start.all():
                raise ArgumentError(
                    "observations: this policy keeps a memory per agent: call it with every agent's observation "
                    f"at once from k = 0 (got instants {np.unique(k)[:4].tolist()} with no episode under way "
                    f"for the leading shape {k.shape})"
                )
            memory = {"k": k.copy(), "switched": np.zeros(k.shape, dtype=bool)}
        elif np.any(~start & (k != memory["k"] + 1)):
            raise ArgumentError(
                "observations: this policy keeps a memory per agent and reads one instant after the other; "
                "an agent's clock skipped or repeated an instant (call it once per instant with every agent's "
                "observation)"
            )
        else:
            probing = ~start & (k <= self.probes)
            if probing.any():
                changed = _changed(memory["rows"], memory["mask"], memory["interval"], rows, mask, interval)
                memory["switched"] = np.where(start, False, memory["switched"] | (probing & changed))
            memory["switched"] = np.where(start, False, memory["switched"])
            memory["k"] = k.copy()
        memory.update(rows=rows.copy(), mask=mask.copy(), interval=np.asarray(interval, dtype=np.float64).copy())
        self._memory = memory
        return memory["switched"]

    def save(self, path: str | Path) -> Path:
        """Write both tables and the header to ``path`` (``.npz``, no pickled objects)."""
        path = Path(path)
        header = {**self.header, "format": REGIME_FORMAT}
        np.savez_compressed(
            path,
            gains=self.gains,
            switching_gains=self.switching_gains,
            header=np.array(json.dumps(header, sort_keys=True)),
        )
        return path


def _changed(
    old_rows: np.ndarray,
    old_mask: np.ndarray,
    old_interval: np.ndarray,
    rows: np.ndarray,
    mask: np.ndarray,
    interval: np.ndarray,
) -> np.ndarray:
    """Whether each agent's rows ``(..., slots, 2, dim)`` are not its previous rows coasted, up to scale (docs: training.md, "The agnostic policy's probe")."""
    xi, eta = old_rows[..., 0, :], old_rows[..., 1, :]
    ratio = (interval / np.where(old_interval > 0, old_interval, 1.0))[..., None, None]
    coasted = np.stack([xi + eta, eta * ratio], axis=-2)
    coasted = np.where(old_mask[..., None, None], coasted, 0.0)
    seen = np.where(mask[..., None, None], rows, 0.0)

    def unit(x: np.ndarray) -> np.ndarray:
        size = np.max(np.abs(x), axis=(-3, -2, -1), keepdims=True)
        return x / np.where(size > 0, size, 1.0)

    differs = np.max(np.abs(unit(coasted) - unit(seen)), axis=(-3, -2, -1)) > TOLERANCE
    return differs | np.any(old_mask != mask, axis=-1)


def read_regime_gains(
    path: Path, gains: np.ndarray, switching: np.ndarray | None, header: dict[str, Any]
) -> RegimeGainPolicy:
    """The two-regime policy of a read ``.npz`` (called by :func:`fxc_env.policies.interval_gains.read_interval_gains`)."""
    if switching is None:
        raise ArgumentError(f"policy: {path} is a {REGIME_FORMAT!r} file without switching_gains")
    return RegimeGainPolicy(gains, switching, header, source=path)


FORMAT_READERS[REGIME_FORMAT] = read_regime_gains
