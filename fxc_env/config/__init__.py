"""Settings: the validated environment configuration, its observation layout, named scenarios, CLI flags.

Layer 2 (above the array maths in :mod:`fxc_env.core`): :func:`make_config` turns keyword
arguments (or a named scenario) into a frozen :class:`EnvConfig` that every engine, environment
and policy reads. The arguments are declared once, in :mod:`fxc_env.config.arguments`; the
signatures, the cards' Arguments tables and the ``fxc`` flags follow that table.
"""

from __future__ import annotations

from fxc_env.config.env_config import (
    RENDER_MODES,
    EnvConfig,
    check_max_cycles,
    check_render_mode,
    config_of,
    make_config,
)
from fxc_env.config.layout import CLOCK_SIZE, ObservationLayout  # in fxc_env.config's names since the first release

__all__ = [
    "CLOCK_SIZE",
    "RENDER_MODES",
    "EnvConfig",
    "ObservationLayout",
    "check_max_cycles",
    "check_render_mode",
    "config_of",
    "make_config",
]
