"""Policies on the local observation: the paper's controller, saved models, the gain network.

Layer 4, beside :mod:`fxc_env.envs` (policies read the observation layout of
:mod:`fxc_env.config`, never an environment object's internals).
"""

# Every gain-schedule format registers its reader with interval_gains.read_interval_gains on import.
from fxc_env.policies import regime_gains  # noqa: F401
