"""BenchMARL's command line with fxc_env's tasks registered (docs: tutorials/benchmarl.md, "Tutorial: BenchMARL").

    python -m fxc_env.envs.benchmarl_run algorithm=mappo task=fxc/rings20-v1

takes every argument of ``python -m benchmarl.run`` (Hydra overrides, ``--multirun``) and runs
BenchMARL's own ``hydra_experiment`` after :func:`fxc_env.envs.benchmarl_task.register`. Plain
``python -m benchmarl.run`` finds an external task only through a Hydra plugin in the
``hydra_plugins`` namespace, a second top-level import name this package does not install.
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
