"""Classical consensus controllers (baselines) and the deadline benchmark.

Each baseline is a policy on the local observation, like :class:`fxc_env.ReferencePolicy`; its module docstring
gives the law, its source paper, the graph class it is proven for, and its parameters. The laws sit in
:mod:`fxc_env.baselines.laws`, the benchmark harness in :mod:`fxc_env.baselines.harness`. The laws are registered
once in :mod:`fxc_env.baselines.registry`; ``fxc benchmark`` (:mod:`fxc_env.baselines.harness.benchmark`) scores them
against the bounds of :mod:`fxc_env.core.optimality` (docs: benchmark.md, "Baselines and the deadline benchmark").

    >>> import fxc_env
    >>> from fxc_env import baselines
    >>> env = fxc_env.parallel_env(action_mode="accel", obs_mode="raw", schedule="uniform", n_intervals=4000)
    >>> policy = baselines.load_policy("linear", env)  # the registered law "linear"; its class in LAW_CLASSES
"""

from __future__ import annotations

from fxc_env.baselines.harness.suite import load_policy
from fxc_env.baselines.registry import LAWS

#: Each registered baseline's class by its class name, read from :data:`~fxc_env.baselines.registry.LAWS` (the
#: reference is :class:`fxc_env.ReferencePolicy`): each is exported under its class name here and on ``fxc_env``
#: (imported there on first use), so a law registered once is exported without a list to edit.
LAW_CLASSES: dict[str, type] = {
    law.policy.__name__: law.policy for law in LAWS.values() if law.policy.__module__.startswith(__name__)
}
globals().update(LAW_CLASSES)

__all__ = [*sorted(LAW_CLASSES), "LAW_CLASSES", "load_policy"]
