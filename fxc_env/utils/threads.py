"""One BLAS/OpenMP thread per process: the environment variables and the two ways to apply them.

Numpy, torch and their BLAS read these variables once, when they start, so a process either
sets them for the children it spawns (:func:`single_threaded_children`) or re-runs itself
with them set (:func:`pin_threads_or_reexec`).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


def single_thread_environment() -> dict[str, str]:
    """The variables that pin a new process to one thread, as a dict."""
    return dict.fromkeys(THREAD_VARIABLES, "1")


def threads_pinned() -> bool:
    """Whether this process was started with one thread per library."""
    return all(os.environ.get(name) == "1" for name in THREAD_VARIABLES)


@contextmanager
def single_threaded_children() -> Iterator[None]:
    """Children spawned inside inherit one BLAS/OpenMP thread each (no oversubscription)."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update(single_thread_environment())
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """Torch uses ``count`` threads inside (small sequential tensors: another thread only waits); the count before after."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def pin_threads_or_reexec(module: str, argv: list[str]) -> None:
    """Re-run ``python -m module argv`` with one thread per library unless that is already so.

    Python's ``-P`` keeps the current directory off ``sys.path``, so a project's own
    package that shares a name with one of ours cannot shadow it in the re-run.
    """
    if threads_pinned():
        return
    env = dict(os.environ, **single_thread_environment())
    sys.stdout.flush()
    os.execve(sys.executable, [sys.executable, "-P", "-m", module, *argv], env)
