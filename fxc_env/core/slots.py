"""The largest absolute value over the padded in-neighbour slots.

Neighbour measurements are stored as ``(..., d_max, dim)`` blocks, zero in unused slots.
``d_max`` is small (a few) while the leading size is huge (up to 10^6 agents), where
numpy's generic reduction over a short trailing axis pays a per-row overhead; a loop over
the ``d_max * dim`` columns, each a vectorised operation over all agents, is about three
times faster. The loop runs over slots, never over agents or episodes.
"""

from __future__ import annotations

import numpy as np

#: Below this many entries one generic reduction is cheaper than the column loop.
SMALL = 4096


def max_abs(block: np.ndarray) -> np.ndarray:
    """``max |block|`` over the last two axes ``(d_max, dim)``; ``(...)``, 0 when there are no slots."""
    columns = block.reshape((*block.shape[:-2], -1))
    if columns.size <= SMALL or columns.shape[-1] == 0:
        return np.abs(columns).max(axis=-1, initial=0.0)
    result = np.zeros(columns.shape[:-1])
    for j in range(columns.shape[-1]):
        np.maximum(result, np.abs(columns[..., j]), out=result)
    return result
