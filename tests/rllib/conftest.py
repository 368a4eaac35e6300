"""Tests that need Ray RLlib: run by `make test` in .venv-rllib (Ray 2.60 pins gymnasium 1.2.2)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def local_ray():
    """One local Ray with 2 CPUs for the whole session; the commands under test join it."""
    import ray

    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield ray
    ray.shutdown()
