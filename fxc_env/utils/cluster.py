"""Ray for the commands that scale out (``fxc train --backend rllib``, ``fxc benchmark --ray``).

Ray is optional (``pip install "fxc-env[rllib]"``; Ray 2.60 pins gymnasium 1.2.2). Without an
address a private local Ray is started for the command and shut down after it; with one
(``auto``, ``HOST:6379`` or ``ray://HOST:10001``) the command joins that cluster, whose
nodes must have fxc-env installed (the same version), and leaves it running.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from fxc_env.core.validation import ArgumentError

INSTALL_HINT = 'pip install "fxc-env[rllib]" (Ray 2.60, which needs gymnasium 1.2.2)'


def import_ray(option: str) -> Any:
    """The ``ray`` module, or a ``ValueError`` naming ``option`` and how to install Ray."""
    try:
        import ray
    except ModuleNotFoundError as exc:
        raise ArgumentError(f"{option}: Ray is not installed in this environment; {INSTALL_HINT}") from exc
    return ray


@contextmanager
def ray_session(option: str, address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """Ray for the duration of a command: joined at ``address``, or started locally (``num_cpus`` cores).

    Reuses a Ray already initialised in this process (and leaves it so); shuts down only
    what it started.
    """
    ray = import_ray(option)
    if ray.is_initialized():
        yield ray
        return
    if address is not None and num_cpus is not None:
        raise ArgumentError(f"{option}: a CPU count applies to a local Ray only, not to the cluster at {address!r}")
    local = {"num_cpus": num_cpus, "include_dashboard": False} if address is None else {}
    ray.init(address=address or "local", logging_level="WARNING", **local)
    try:
        yield ray
    finally:
        ray.shutdown()
