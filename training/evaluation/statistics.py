"""Aggregates over training seeds, with stratified bootstrap confidence intervals (numpy, batched).

A score matrix ``X`` of shape ``(R, S)``: R training seeds (runs) by S initial states (episodes).
:func:`median`, :func:`iqm` (rliable's ``aggregate_iqm``) and :func:`stratified_bootstrap`
(seeds, then initial states within each, resampled; percentile interval; Agarwal et al., NeurIPS
2021) pool every run and episode (docs: results.md, "The aggregates and the bootstrap").

Every function is batched over leading dimensions and takes scores as float64 arrays; ``inf``
(a run that diverged) sorts as the largest score, NaN is refused.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from fxc_env.core.validation import ArgumentError, choice, integer

#: Bootstrap replicates of :func:`stratified_bootstrap` unless told (the percentile interval's
#: endpoints move by ~1e-2 of its width between generator seeds at this count).
DEFAULT_REPS = 10_000
#: Seed of the bootstrap's generator unless told: the same scores give the same interval.
DEFAULT_BOOTSTRAP_SEED = 0
#: Replicates drawn per block (bounds the memory of one block to ``block × R × S`` floats).
_BLOCK = 1_000


def median(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """The median along ``axis`` (the mean of the two middle scores for an even count)."""
    return np.median(np.asarray(scores, dtype=np.float64), axis=axis)


def iqm(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """The interquartile mean along ``axis``: the mean of the sorted scores without ``floor(n/4)`` at each end.

    ``n`` is the length of ``axis``; ``iqm([0, 1, ..., 7]) = mean(2, 3, 4, 5) = 3.5``. For
    ``n < 4`` nothing is dropped (the mean). Equals ``scipy.stats.trim_mean(scores, 0.25, axis)``.
    """
    ordered = np.sort(np.asarray(scores, dtype=np.float64), axis=axis)
    n = ordered.shape[axis]
    if n == 0:
        raise ArgumentError("scores: the interquartile mean of no scores is undefined")
    cut = n // 4
    return np.take(ordered, np.arange(cut, n - cut), axis=axis).mean(axis=axis)


#: Aggregates by name: each maps ``(..., n)`` scores to ``(...)`` along the last axis.
AGGREGATES: dict[str, Callable[[np.ndarray], np.ndarray]] = {"median": median, "iqm": iqm}


@dataclass(frozen=True)
class Interval:
    """An aggregate and its bootstrap confidence interval.

    Attributes:
        estimate: the aggregate of the scores as measured.
        low, high: the percentile interval's ends (``confidence`` of the replicates between them).
        confidence: its nominal coverage (0.95 for a 95 % interval).
        reps: bootstrap replicates drawn.
        seed: the seed of the bootstrap's generator.
    """

    estimate: float
    low: float
    high: float
    confidence: float
    reps: int
    seed: int

    def as_dict(self) -> dict[str, float | int]:
        """Plain JSON values (``inf`` stays a float: ``json`` writes it as ``Infinity``)."""
        return asdict(self)


def checked_scores(scores: object, name: str = "scores") -> np.ndarray:
    """``scores`` as a float64 ``(R, S)`` array: at least one run and one state, no NaN."""
    array = np.asarray(scores, dtype=np.float64)
    if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
        raise ArgumentError(f"{name}: expected a (training seeds, initial states) array, got shape {array.shape}")
    if np.isnan(array).any():
        raise ArgumentError(f"{name}: NaN scores cannot be ranked (use inf for a run that diverged)")
    return array


def bootstrap_replicates(
    scores: np.ndarray,
    aggregate: Callable[[np.ndarray], np.ndarray],
    reps: int = DEFAULT_REPS,
    seed: int = DEFAULT_BOOTSTRAP_SEED,
) -> np.ndarray:
    """``(reps,)`` aggregates of two-level bootstrap resamples of the ``(R, S)`` ``scores`` (docs: results.md, "The aggregates and the bootstrap").

    Replicate b pools ``X[r_i, s_ij]`` for ``i < R``, ``j < S`` (seeds ``r_i`` drawn with
    replacement, then initial states ``s_ij`` within each) and applies ``aggregate`` along the
    last axis. Drawn from ``np.random.default_rng(seed)`` in blocks, so a given ``seed`` and
    ``reps`` give the same replicates on every machine.
    """
    x = checked_scores(scores)
    reps = integer("reps", reps, 1)
    runs, states = x.shape
    rng = np.random.default_rng(seed)
    out = np.empty(reps)
    for start in range(0, reps, _BLOCK):
        block = min(_BLOCK, reps - start)
        run_index = rng.integers(0, runs, size=(block, runs, 1))
        state_index = rng.integers(0, states, size=(block, runs, states))
        out[start : start + block] = aggregate(x[run_index, state_index].reshape(block, runs * states))
    return out


def stratified_bootstrap(
    scores: object,
    aggregate: str | Callable[[np.ndarray], np.ndarray] = "iqm",
    *,
    confidence: float = 0.95,
    reps: int = DEFAULT_REPS,
    seed: int = DEFAULT_BOOTSTRAP_SEED,
) -> Interval:
    """The ``aggregate`` (``"median"``, ``"iqm"`` or a batched callable) of ``(R, S)`` scores and its CI.

    The estimate pools all ``R × S`` scores; the interval is the ``(1 - confidence) / 2`` and
    ``(1 + confidence) / 2`` quantiles of :func:`bootstrap_replicates` (the percentile
    bootstrap; the replicates just outside, so the ends are replicates themselves), so it is
    reproducible for a given ``seed``.
    """
    if isinstance(aggregate, str):
        aggregate = AGGREGATES[choice("aggregate", aggregate, tuple(AGGREGATES))]
    if not (isinstance(confidence, float | int) and 0.0 < float(confidence) < 1.0):
        raise ArgumentError(f"confidence: expected a number in (0, 1), got {confidence!r}")
    x = checked_scores(scores)
    replicates = bootstrap_replicates(x, aggregate, reps, seed)
    tail = (1.0 - float(confidence)) / 2.0
    # Order statistics, not interpolation: inf replicates (diverged runs) stay inf instead of NaN.
    low = np.quantile(replicates, tail, method="lower")
    high = np.quantile(replicates, 1.0 - tail, method="higher")
    estimate = float(np.asarray(aggregate(x.reshape(1, -1)))[0])
    return Interval(estimate, float(low), float(high), float(confidence), int(reps), int(seed))


def decades(relative_error: object, floor: float = 1e-12) -> np.ndarray:
    """``log10(max(D(T_s)/D(0), floor))``: a deadline error in decades, floored at ``floor``.

    The benchmark's log column (docs: benchmark.md, "Baselines and the deadline benchmark"): errors below ``floor`` (1e-12, the
    float64 floor of the paper's example) all count as reached; ``inf`` (diverged) stays ``inf``.
    """
    error = np.asarray(relative_error, dtype=np.float64)
    if np.isnan(error).any():
        raise ArgumentError("relative_error: NaN deadline errors cannot be scored")
    return np.log10(np.maximum(error, floor))
