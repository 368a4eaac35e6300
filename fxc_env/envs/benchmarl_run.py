"""BenchMARL's command line with fxc_env's tasks registered (docs: tutorials/benchmarl.md, "Tutorial: BenchMARL").

    python -m fxc_env.envs.benchmarl_run algorithm=mappo task=fxc/rings20-v1

takes every argument of ``python -m benchmarl.run`` (Hydra overrides, ``--multirun``) and runs
BenchMARL's own ``hydra_experiment`` after :func:`fxc_env.envs.benchmarl_task.register`. An
installed package needs it not: plain ``python -m benchmarl.run`` finds the tasks through the
Hydra plugin ``hydra_plugins.fxc_env``. This entry serves where Hydra sees no plugin (a source
checkout on ``sys.path``, not installed).
"""

from __future__ import annotations


def main() -> None:
    """Register the ``fxc/<task>`` tasks, then hand ``sys.argv`` to BenchMARL's Hydra entry point."""
    from benchmarl.run import hydra_experiment

    from fxc_env.envs.benchmarl_task import register

    register()
    hydra_experiment()


if __name__ == "__main__":
    main()
