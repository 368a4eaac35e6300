"""Hydra plugin of fxc_env: BenchMARL's command line finds the ``fxc/<task>`` tasks (README "BenchMARL").

Hydra imports every module under the ``hydra_plugins`` namespace when it builds a search path.
This one does nothing else at import; when the application is BenchMARL (``benchmarl`` already
imported, as ``python -m benchmarl.run`` does) it registers fxc_env's tasks
(:func:`fxc_env.envs.benchmarl_task.register`), so ``python -m benchmarl.run algorithm=mappo
task=fxc/rings20-v1`` runs without any edit of BenchMARL's files.
"""

from __future__ import annotations

import sys

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class FxcBenchmarlTasks(SearchPathPlugin):
    """Registers the BenchMARL tasks in BenchMARL's registry and Hydra's ``task`` group (config store)."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        if "benchmarl" in sys.modules:  # other Hydra applications never import fxc_env through this plugin
            from fxc_env.envs.benchmarl_task import register

            register()
