"""Timing blocks shared by every table: alternation, rates, calibrated counts, the machine line.

Each table alternates its contenders round by round (:func:`alternate`) so that all see the
same machine state, and reports the median rate over rounds.
"""

from __future__ import annotations

import importlib.util
import os
import platform
import statistics
import time
from collections.abc import Callable

import numpy as np

#: Seconds of one timed block (the number of calls is calibrated per contender).
BLOCK_SECONDS = 0.25


def machine_description() -> str:
    """CPU model, core count, Python and library versions."""
    model = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import torch

    return (
        f"{model}, {os.cpu_count()} cores, {platform.system()} {platform.machine()}, Python {platform.python_version()}, "
        f"numpy {np.__version__}, torch {torch.__version__} (threads: {torch.get_num_threads()})"
    )


def alternate(contenders: dict[str, Callable[[], float]], rounds: int) -> dict[str, float]:
    """Run each contender's timed block once per round, in turn; median rate per contender."""
    rates: dict[str, list[float]] = {name: [] for name in contenders}
    for _ in range(rounds):
        for name, run in contenders.items():
            rates[name].append(run())
    return {name: statistics.median(values) for name, values in rates.items()}


def timed_rate(step: Callable[[], None], count: int, sync: Callable[[], None] | None = None) -> float:
    """Calls of ``step`` per second over ``count`` calls (``sync``, e.g. ``torch.cuda.synchronize``, on both ends)."""
    if sync is not None:
        sync()
    start = time.perf_counter()
    for _ in range(count):
        step()
    if sync is not None:
        sync()
    return count / (time.perf_counter() - start)


def calibrated_count(
    step: Callable[[], None], seconds: float, sync: Callable[[], None] | None = None, most: int = 2000
) -> int:
    """How many calls of ``step`` take about ``seconds`` (at least 3): one warm-up call, then 3 timed."""
    step()
    return int(min(most, max(3, timed_rate(step, 3, sync) * seconds)))


def met(met: bool) -> str:
    """A goal line's verdict: ``met`` or ``not met``."""
    return "met" if met else "not met"


def importable(name: str) -> bool:
    """Whether module ``name`` can be imported here (without importing it)."""
    return importlib.util.find_spec(name) is not None
