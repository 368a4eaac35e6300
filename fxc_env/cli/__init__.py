"""The ``fxc`` command (top layer): ``simulate``, ``evaluate``, ``benchmark``, ``train``, ``speed``."""

from __future__ import annotations

from fxc_env.cli.main import UsageError, main

__all__ = ["UsageError", "main"]
