"""Disagreement measures and per-episode metrics (the env card's Rewards; docs: benchmark.md, "Baselines and the deadline benchmark").

``e_x = max_ij ||x_i - x_j||_2`` (the diameter of the agents' positions), ``e_v`` likewise,
and the disagreement ``D = e_x + T_s e_v`` (metres), which weighs a velocity mismatch by
how far it would carry an agent over the whole horizon. Arrays are ``(..., N, dim)``.

Cost of :func:`spread` per episode: ``dim = 1`` O(N) (max - min); ``dim = 2, 3`` O(N) plus
O(S log S) for the S candidates its filters leave (a handful for the clouds agents form; see
there for the worst case); ``dim > 3`` O(N^2 dim), all pairs. Exact throughout: for ``dim > 1``
bitwise the all-pairs value.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass

import numpy as np

from fxc_env.core.arrays import is_numpy, namespace

#: Thresholds of the settling-time metric ``t_eps``.
SETTLING_THRESHOLDS = (1e-2, 1e-6)
#: ``settled_interval``: the interval after which ``D(t_k) / D(0)`` stayed below this.
SETTLED_TOLERANCE = 1e-9
#: Every threshold an episode's trackers follow (the last instant at or above each).
TRACKED_THRESHOLDS = (*SETTLING_THRESHOLDS, SETTLED_TOLERANCE)

#: ``dim > 1``: :func:`spread` compares every pair, vectorised over the batch, up to this many
#: agents, or up to :data:`PAIRWISE_PAIRS` pairs over the whole batch (measured crossovers).
PAIRWISE_AGENTS = 32
PAIRWISE_PAIRS = 1 << 15
#: Up to this many candidates left by the filter, all their pairs are compared; above, the pruned search.
PAIRWISE_CANDIDATES = 256
#: Elements of one block of pairwise differences (bounds the memory of the all-pairs comparison).
_PAIRWISE_BLOCK = 1 << 16
#: Points per leaf of the pruned search's k-d tree, and leaf pairs compared per batch.
_LEAF = 16
_LEAF_BATCH = 1024
#: Directions whose extreme points seed the search when the filters leave many candidates.
_DIRECTIONS = 32
#: Further farthest-point sweeps, at most, when the first pair leaves many candidates.
_SWEEPS = 3
#: Relative margin of every filter and pruning test; rounding is ~1e-15, far below it.
_MARGIN = 1e-9
#: Episodes whose largest squared centred norm lies outside this range (squares near underflow
#: or overflow) are filtered on a copy scaled by a power of two.
_NORMAL_RANGE = (2.0**-900, 2.0**1000)


def spread(z: np.ndarray) -> np.ndarray:
    """Diameter ``max_ij ||z_i - z_j||_2`` over the agent axis (-2); shape ``(...)``.

    ``dim = 1``: ``max - min``, O(N). ``dim > 1``: the value is the all-pairs comparison's,
    bit for bit (coordinates centred on the centroid, components added in order): every pair
    up to :data:`PAIRWISE_AGENTS` agents or :data:`PAIRWISE_PAIRS` pairs, or ``dim > 3``;
    above that, in 2-D and 3-D, only the pairs that could beat a value already attained
    (farthest-point sweeps, ball filters with a 1e-9 margin, a k-d tree's branch and bound:
    exact, no tolerance; docs: performance.md, "The exact diameter").

    Non-finite entries make that episode NaN, as the all-pairs arithmetic does (a point
    with an infinite coordinate is NaN away from itself). Where squared distances would
    underflow or overflow (centred coordinates below about 1e-135 or above 1e150), the
    filters run on a copy scaled by a power of two and the value still comes from the
    unscaled arithmetic, which then agrees with the all-pairs value to its own rounding.
    """
    z = np.asarray(z)
    if z.shape[-1] == 1:
        return np.max(z[..., 0], axis=-1) - np.min(z[..., 0], axis=-1)
    lead, (n, dim) = z.shape[:-2], z.shape[-2:]
    if n == 0 or math.prod(lead) == 0:
        return np.zeros(lead)[()]
    centred = _centred_components(z)  # (dim, B, N)
    pairwise = n <= PAIRWISE_AGENTS or centred.shape[1] * n * n <= PAIRWISE_PAIRS or dim > 3
    largest = _pairwise_max(centred) if pairwise else _filtered_max(centred)
    return np.sqrt(largest).reshape(lead)[()]


def _centred_components(z: np.ndarray) -> np.ndarray:
    """``(dim, B, N)`` float64 coordinates minus the per-episode centroid (summed in agent order)."""
    n, dim = z.shape[-2:]
    components = np.moveaxis(np.asarray(z, dtype=np.float64).reshape(-1, n, dim), -1, 0)
    components = np.array(components, order="C")  # always a copy: centred in place below
    # cumsum adds in agent order, as numpy's mean over the agent axis does on C-ordered arrays.
    components -= np.cumsum(components, axis=-1)[..., -1:] / n
    return components


def _squared_distances(points: np.ndarray, centre: np.ndarray | None) -> np.ndarray:
    """``sum_d fl(p_d - c_d)^2`` for points ``(dim, B, N)`` and one centre per episode ``(dim, B)``.

    ``centre = None``: the origin (squared norms). Components are added in order, as the
    all-pairs comparison does, so the value of a pair is the same wherever it is computed.
    """
    total = None
    for d, component in enumerate(points):
        if centre is None:
            square = component * component
        else:
            square = component - centre[d][:, None]
            square *= square
        if total is None:
            total = square
        else:
            total += square
    return total


def _pairwise_max(points: np.ndarray) -> np.ndarray:
    """Largest squared distance over all pairs of ``(dim, B, N)`` points, per episode ``(B,)``."""
    _, b, n = points.shape
    rows = max(1, min(n, _PAIRWISE_BLOCK // n))
    episodes = max(1, _PAIRWISE_BLOCK // (rows * n))
    result = np.empty(b)
    for first in range(0, b, episodes):
        group = points[:, first : first + episodes]
        best = None
        for start in range(0, n, rows):
            total = None
            for component in group:
                square = component[:, start : start + rows, None] - component[:, None, :]
                square *= square
                if total is None:
                    total = square
                else:
                    total += square
            block = total.max(axis=(-2, -1))
            best = block if best is None else np.maximum(best, block)
        result[first : first + episodes] = best
    return result


def _filtered_max(centred: np.ndarray) -> np.ndarray:
    """Largest squared distance per episode of ``(dim, B, N)`` centred points (see :func:`spread`)."""
    squared_norms = _squared_distances(centred, None)
    start = squared_norms.argmax(axis=-1)  # NaN counts as largest: those episodes are not normal
    reach = squared_norms[np.arange(len(start)), start]
    normal = (reach >= _NORMAL_RANGE[0]) & (reach <= _NORMAL_RANGE[1])
    if normal.all():
        return _search(centred, centred, squared_norms, start)
    result = np.empty(len(start))
    if normal.any():
        chosen = np.compress(normal, centred, axis=1)
        result[normal] = _search(chosen, chosen, squared_norms[normal], start[normal])
    for episode in np.flatnonzero(~normal):
        points = centred[:, episode : episode + 1]
        magnitude = np.max(np.abs(points))
        if not np.isfinite(magnitude):
            result[episode] = np.nan
        elif magnitude == 0:
            result[episode] = 0.0
        else:
            scaled = np.ldexp(points, -np.frexp(magnitude)[1])
            norms = _squared_distances(scaled, None)
            result[episode] = _search(scaled, points, norms, norms.argmax(axis=-1))[0]
    return result


def _search(geometry: np.ndarray, points: np.ndarray, squared_norms: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Filter and search on ``geometry`` ``(dim, B, N)``; values from ``points`` (it, or it unscaled).

    ``squared_norms``: ``|p|^2`` from the centroid, ``(B, N)``; ``start``: its argmax per episode.
    """
    b = geometry.shape[1]
    episodes = np.arange(b)
    # A farthest-point sweep from the point farthest from the centroid: a pair and its value.
    from_start = _squared_distances(geometry, geometry[:, episodes, start])
    end = from_start.argmax(axis=-1)
    lower = from_start[episodes, end]
    # Ball filter around the centroid (the origin).
    threshold = _threshold(lower, np.sqrt(squared_norms[episodes, start]))
    rows, columns = np.nonzero(squared_norms >= threshold[:, None])
    counts = np.bincount(rows, minlength=b)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ends = points[:, episodes[:, None], np.stack([start, end], axis=-1)]
    result = lower.copy() if geometry is points else _pairwise_max(ends)
    small = counts <= PAIRWISE_CANDIDATES
    if small.any():
        # Each chosen episode's survivors in one row, padded by repeating its start (no new pair).
        chosen = np.flatnonzero(small)
        index = np.repeat(start[chosen, None], max(1, int(counts[chosen].max())), axis=1)
        inside = small[rows]
        within = np.arange(len(rows)) - offsets[rows]  # each survivor's place among its episode's
        index[np.searchsorted(chosen, rows[inside]), within[inside]] = columns[inside]
        result[chosen] = np.maximum(result[chosen], _pairwise_max(points[:, chosen[:, None], index]))
    # lower = 0: every point is at distance 0 from the start, so all coincide (consensus reached).
    for episode in np.flatnonzero(~small & (lower > 0)):
        keep = squared_norms[episode] >= threshold[episode]
        found = _search_many(geometry[:, episode], points[:, episode], keep, start[episode], end[episode])
        result[episode] = max(result[episode], found)
    return result


def _search_many(geometry: np.ndarray, points: np.ndarray, keep: np.ndarray, start: int, end: int) -> float:
    """One episode ``(dim, N)`` whose centroid filter ``keep`` left many points: its largest value.

    More farthest-point sweeps (from the last point found, while the pair grows), then a
    second ball filter around the middle of the pair over all points: it holds where the
    centroid's does not (a cloud offset from its rounded centroid, near consensus). Then
    duplicates go (a repeated point adds no pair value), and all pairs or the k-d tree search.
    """
    lower = _squared_distances(geometry[:, None, [start]], geometry[:, [end]])[0, 0]
    for _ in range(_SWEEPS):
        from_end = _squared_distances(geometry[:, None], geometry[:, [end]])[0]
        farthest = int(from_end.argmax())
        if not from_end[farthest] > lower:
            break
        start, end, lower = end, farthest, from_end[farthest]
    middle = (geometry[:, start] + geometry[:, end]) * 0.5
    from_middle = _squared_distances(geometry[:, None], middle[:, None])[0]
    keep &= from_middle >= _threshold(lower, np.sqrt(from_middle.max()))
    keep[[start, end]] = True
    survivors = np.flatnonzero(keep)
    if len(survivors) > PAIRWISE_CANDIDATES:
        # np.take, not fancy indexing: the latter gives (dim, S) arrays in Fortran order.
        order = np.lexsort(np.take(geometry, survivors, axis=1)[::-1])
        survivors = survivors[order]
        ordered = np.take(geometry, survivors, axis=1)
        new = np.ones(len(order), dtype=bool)
        new[1:] = (ordered[:, 1:] != ordered[:, :-1]).any(axis=0)
        survivors = survivors[new]
    if len(survivors) <= PAIRWISE_CANDIDATES:
        return float(_pairwise_max(np.take(points, survivors, axis=1)[:, None])[0])
    # A better pair, from the points farthest out along fixed directions, tightens the
    # filter (same centre, larger lower bound) and the search's pruning.
    candidates = np.take(geometry, survivors, axis=1)
    value, pair = _extreme_pair(candidates)
    if value > lower:
        lower, (start, end) = value, survivors[list(pair)]
        kept = from_middle[survivors] >= _threshold(lower, np.sqrt(from_middle.max()))
        kept[list(pair)] = True
        survivors, candidates = survivors[kept], candidates[:, kept]
    found = _farthest_pair(candidates, lower)
    ends = [start, end] if found is None else survivors[list(found)]
    return float(_pairwise_max(np.take(points, ends, axis=1)[:, None])[0])


def _extreme_pair(points: np.ndarray) -> tuple[float, tuple[int, int]]:
    """The largest squared distance among the points of ``(dim, S)`` farthest out along :func:`_directions`, and its pair."""
    along = _directions(len(points)) @ points
    ends = np.unique(np.concatenate([along.argmax(axis=-1), along.argmin(axis=-1)]))
    chosen = np.take(points, ends, axis=1)
    total = None
    for component in chosen:
        square = component[:, None] - component[None, :]
        square *= square
        if total is None:
            total = square
        else:
            total += square
    row, column = np.unravel_index(int(total.argmax()), total.shape)
    return float(total[row, column]), (int(ends[row]), int(ends[column]))


@functools.cache
def _directions(dim: int) -> np.ndarray:
    """``(K, dim)`` unit vectors spread over a half circle (dim 2) or a sphere (Fibonacci lattice), else the axes."""
    if dim == 2:
        angles = np.pi * np.arange(_DIRECTIONS) / _DIRECTIONS
        return np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    if dim == 3:
        k = np.arange(_DIRECTIONS) + 0.5
        polar = np.arccos(1 - 2 * k / _DIRECTIONS)
        azimuth = np.pi * (1 + 5**0.5) * k
        return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=-1)
    return np.eye(dim)


def _threshold(lower: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Squared distance from a centre below which no end of a pair longer than ``sqrt(lower)`` lies.

    ``reach``: the largest distance of any point from that centre. A pair ``(a, b)`` longer
    than ``sqrt(lower)`` has ``|a - o| >= |a - b| - |b - o| > sqrt(lower) - reach``; the
    relative margins (:data:`_MARGIN`) cover the rounding of every computed distance.
    """
    threshold = np.sqrt(lower) * (1 - _MARGIN) - reach * (1 + _MARGIN)
    return np.where(threshold > 0, threshold * threshold * (1 - _MARGIN), 0.0)


def _farthest_pair(points: np.ndarray, lower: float) -> tuple[int, int] | None:
    """The pair of ``points`` ``(dim, S)`` with the largest squared distance, if above ``lower``.

    Branch and bound over pairs of boxes of a median-split k-d tree: a pair of boxes is
    dropped when the largest squared distance between them, with :data:`_MARGIN`, is not
    above the best value found; the leaves' pairs are compared one by one.
    """
    dim, n = points.shape
    levels = max(0, math.ceil(math.log2(n / _LEAF)))
    size = _LEAF << levels
    order = np.zeros(size, dtype=np.intp)  # padding repeats point 0: no new pair
    order[:n] = np.arange(n)
    tree = np.take(points, order, axis=1)  # C order (fancy indexing would give Fortran order)
    for level in range(levels):
        chunks, width = 1 << level, size >> level
        view = tree.reshape(dim, chunks, width)
        axis = (view.max(axis=-1) - view.min(axis=-1)).argmax(axis=0)
        halves = np.argpartition(view[axis, np.arange(chunks)], width // 2, axis=-1)
        permutation = (halves + (np.arange(chunks) * width)[:, None]).ravel()
        tree, order = np.take(tree, permutation, axis=1), order[permutation]
    leaves = tree.reshape(dim, size // _LEAF, _LEAF)
    lows, highs = [leaves.min(axis=-1)], [leaves.max(axis=-1)]
    for _ in range(levels):
        lows.append(np.minimum(lows[-1][:, 0::2], lows[-1][:, 1::2]))
        highs.append(np.maximum(highs[-1][:, 0::2], highs[-1][:, 1::2]))
    lows.reverse()
    highs.reverse()
    best, found = lower, None
    first = second = np.zeros(1, dtype=np.intp)
    for level in range(1, levels + 1):
        a, b = 2 * first, 2 * second
        first = np.concatenate([a, a, a + 1, a + 1])
        second = np.concatenate([b, b + 1, b, b + 1])
        ordered = first <= second
        first, second = first[ordered], second[ordered]
        alive = _box_bound(lows[level], highs[level], first, second) * (1 + _MARGIN) > best
        first, second = first[alive], second[alive]
    bounds = _box_bound(lows[levels], highs[levels], first, second)
    by_bound = np.argsort(-bounds, kind="stable")
    first, second, bounds = first[by_bound], second[by_bound], bounds[by_bound]
    for start in range(0, len(first), _LEAF_BATCH):
        if not bounds[start] * (1 + _MARGIN) > best:
            break
        a, b = first[start : start + _LEAF_BATCH], second[start : start + _LEAF_BATCH]
        total = None
        for component in leaves:
            square = component[a, :, None] - component[b, None, :]
            square *= square
            if total is None:
                total = square
            else:
                total += square
        flat = int(total.argmax())
        value = total.reshape(-1)[flat]
        if value > best:
            pair, rest = divmod(flat, _LEAF * _LEAF)
            row, column = divmod(rest, _LEAF)
            best = value
            found = (int(order[a[pair] * _LEAF + row]), int(order[b[pair] * _LEAF + column]))
    return found


def _box_bound(lows: np.ndarray, highs: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Largest squared distance between boxes ``first`` and ``second`` (``(dim, boxes)`` corners)."""
    total = np.zeros(len(first))
    for low, high in zip(lows, highs, strict=True):
        gap = np.maximum(high[first] - low[second], high[second] - low[first])
        total += gap * gap
    return total


def disagreement(x: np.ndarray, v: np.ndarray, settling_time: float) -> np.ndarray:
    """``D = e_x + T_s e_v`` in metres, shape ``(...)``; numpy arrays or torch tensors (:func:`spread_any`)."""
    return spread_any(x) + settling_time * spread_any(v)


def spread_any(z):
    """:func:`spread` of a numpy array, or the same diameter of any array API array (a torch tensor).

    The generic form: ``max - min`` for ``dim = 1``; for ``dim > 1`` every pair's distance, in
    blocks of agents (O(N^2 dim) per episode: meant for the batches of many small episodes a
    device steps; the pruned search above serves numpy's single large episodes). Every pair
    value is computed as the all-pairs comparison does, so both agree to rounding.
    """
    xp = namespace(z)
    if is_numpy(xp):
        return spread(z)
    if z.shape[-1] == 1:
        return xp.max(z[..., 0], axis=-1) - xp.min(z[..., 0], axis=-1)
    centred = z - xp.mean(z, axis=-2, keepdims=True)
    n = z.shape[-2]
    block = max(1, _PAIRWISE_BLOCK * 16 // max(1, n * z.shape[-1]))
    best = None
    for start in range(0, n, block):
        difference = centred[..., start : start + block, None, :] - centred[..., None, :, :]
        largest = xp.max(xp.sum(difference * difference, axis=-1), axis=(-2, -1))
        best = largest if best is None else xp.maximum(best, largest)
    return xp.sqrt(best)


def reward_floor(initial_disagreement: np.ndarray, relative_floor: float) -> np.ndarray:
    """Floor ``f`` of the log-reward: ``relative_floor * D(0)``, or 1 where ``D(0) = 0``."""
    xp = namespace(initial_disagreement)
    return xp.where(initial_disagreement > 0, relative_floor * initial_disagreement, xp.ones_like(initial_disagreement))


@dataclass(frozen=True)
class EpisodeMetrics:
    """The per-episode figures of the deadline benchmark. Lengths in metres, times in seconds.

    ``t_eps_*`` is the first sampling instant from which ``D(t_k) / D(0) < eps`` at every
    later sampling instant (``inf`` if that never happens by ``T_s``).
    ``predicted_*`` come from Theorems 1-2 (``xi``) and are NaN where they do not apply
    (random switching) or ``xi`` is not computed (very large N); ``achieved_*`` are the
    agents' means at the end. ``saturated_fraction`` is the share of agent-time spent at
    the input limit ``u_max`` (mean over components; 0 without a limit).
    For ``dim > 1`` the predicted and achieved values are the first component.

    How far from optimal (docs: optimality.md, "How far from optimal"): ``energy_bound`` is ``E*``
    and ``energy_ratio`` is ``energy / E*`` (NaN where ``E* = 0``); ``settled_interval`` (below
    :data:`SETTLED_TOLERANCE`) compares with ``radius_bound`` and ``all_roots_bound`` (NaN for
    random switching and above 2000 agents; ``propagation_bound`` is its deprecated copy);
    ``noise_floor`` (``D(T_s) / D(0)``) and ``input_floor`` (m/s²) are the floors of
    :mod:`fxc_env.core.floors`, NaN when their setting is off, for other agent models, and
    ``noise_floor`` also with random switching and above 200 agents. ``resolution_floor``
    (``D(T_s) / D(0)``, under ``obs_resolution``) is the worst case of a law that applies no input
    while it reads only zeros, over the initial states whose every reading is 0 (not a bound on each
    episode); NaN without a quantum, under noise, with random switching and for other models.
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
    energy_bound: float
    energy_ratio: float
    settled_interval: float
    radius_bound: float
    all_roots_bound: float
    propagation_bound: float
    noise_floor: float = math.nan
    input_floor: float = math.nan
    resolution_floor: float = math.nan

    def as_dict(self) -> dict[str, float | int | None]:
        """Plain dict for JSON (non-finite values become ``None``)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}
