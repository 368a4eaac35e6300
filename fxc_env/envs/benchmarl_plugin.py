"""fxc_env's tasks in BenchMARL's own command line: a Hydra search-path plugin (docs: tutorials/benchmarl.md).

Hydra runs the code of a package it was not told about only through a plugin module in its
``hydra_plugins`` namespace. The wheel installs the one import name ``fxc_env``, so this module is
not there: ``python -m fxc_env.envs.benchmarl_run --install-plugin`` copies it to
``hydra_plugins/fxc_env_benchmarl.py`` in the interpreter's site-packages, with a last line holding
the SHA-256 of the rest, so that a copy edited since is never replaced or removed (``--uninstall-plugin``
removes an unedited one). Then BenchMARL's command line runs the tasks as it is::

    python -m benchmarl.run algorithm=mappo task=fxc/rings20-v1 "experiment.loggers=[csv]"

Hydra imports every plugin module of every Hydra application, so this one imports nothing but
Hydra at import time. When Hydra builds a config search path in a process that has imported
BenchMARL, it calls :func:`fxc_env.envs.benchmarl_task.register` (the tasks into BenchMARL's
``task_config_registry`` and Hydra's config store, which the search path already reads) and adds
no path of its own; any other Hydra application runs as if it were not installed.
"""

from __future__ import annotations

import sys
import warnings

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class FxcEnvTasks(SearchPathPlugin):
    """Register the ``fxc/<task>`` tasks for a BenchMARL application before Hydra composes its config."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        if "benchmarl" not in sys.modules:  # not a BenchMARL application: nothing to do, nothing imported
            return
        try:
            from fxc_env.envs.benchmarl_task import register
        except ModuleNotFoundError as error:  # fxc_env uninstalled, this copy left behind
            warnings.warn(
                f"{__file__}: fxc_env's BenchMARL tasks are not registered ({error}); remove this file, "
                "or reinstall fxc-env[benchmarl]",
                stacklevel=2,
            )
            return
        register()
