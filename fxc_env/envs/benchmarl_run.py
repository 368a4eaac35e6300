"""BenchMARL's command line for fxc_env's tasks (docs: tutorials/benchmarl.md, "Tutorial: BenchMARL").

Two routes to the same run::

    python -m fxc_env.envs.benchmarl_run --install-plugin       # once per environment, then
    python -m benchmarl.run algorithm=mappo task=fxc/rings20-v1  # BenchMARL's own command line

    python -m fxc_env.envs.benchmarl_run algorithm=mappo task=fxc/rings20-v1   # nothing installed

``--install-plugin`` copies :mod:`fxc_env.envs.benchmarl_plugin` to
``hydra_plugins/fxc_env_benchmarl.py`` in this interpreter's site-packages (or ``--target DIR``), the one
place Hydra looks for another package's code; ``--uninstall-plugin`` removes it. Without it, this
module takes every argument of ``python -m benchmarl.run`` (Hydra overrides, ``--multirun``) and runs
BenchMARL's own ``hydra_experiment`` after :func:`fxc_env.envs.benchmarl_task.register`.
"""

from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

from fxc_env.core.validation import ArgumentError

#: Where the plugin goes, under the target folder (a module of Hydra's ``hydra_plugins`` namespace).
PLUGIN_PATH = Path("hydra_plugins", "fxc_env_benchmarl.py")
#: The plugin's source: this package's module, copied verbatim.
PLUGIN_SOURCE = Path(__file__).with_name("benchmarl_plugin.py")
USAGE = (
    "usage: python -m fxc_env.envs.benchmarl_run (--install-plugin | --uninstall-plugin) [--target DIR]\n"
    "       python -m fxc_env.envs.benchmarl_run [python -m benchmarl.run's arguments]"
)


def install_plugin(target: str | Path | None = None) -> Path:
    """Write the plugin to ``<target>/hydra_plugins/fxc_env_benchmarl.py`` and return its path.

    ``target`` defaults to this interpreter's site-packages (``sysconfig``'s ``purelib``). A file
    already there is replaced only if it is an earlier copy of the plugin (its first line).
    """
    path = _plugin_path(target)
    source = PLUGIN_SOURCE.read_text()
    if path.exists() and path.read_text().splitlines()[:1] != source.splitlines()[:1]:
        raise ArgumentError(f"target: {path} exists and is not fxc_env's BenchMARL plugin; nothing was written")
    path.parent.mkdir(exist_ok=True)  # a namespace package: no __init__.py
    path.write_text(source)
    return path


def uninstall_plugin(target: str | Path | None = None) -> Path | None:
    """Remove the plugin written by :func:`install_plugin`; return its path, or ``None`` if none was there."""
    path = _plugin_path(target)
    if not path.exists():
        return None
    if path.read_text().splitlines()[:1] != PLUGIN_SOURCE.read_text().splitlines()[:1]:
        raise ArgumentError(f"target: {path} is not fxc_env's BenchMARL plugin; nothing was removed")
    path.unlink()
    if not any(path.parent.iterdir()):
        path.parent.rmdir()
    return path


def _plugin_path(target: str | Path | None) -> Path:
    folder = Path(sysconfig.get_path("purelib") if target is None else target)
    if not folder.is_dir():
        raise ArgumentError(f"target: expected an existing folder on sys.path (site-packages), got {str(folder)!r}")
    return folder / PLUGIN_PATH


def main(argv: list[str] | None = None) -> int:
    """Install or remove the plugin (``--install-plugin``/``--uninstall-plugin``), or run BenchMARL's command line."""
    argv = sys.argv[1:] if argv is None else argv
    actions = [flag for flag in ("--install-plugin", "--uninstall-plugin") if flag in argv]
    if not actions:
        from benchmarl.run import hydra_experiment

        from fxc_env.envs.benchmarl_task import register

        register()
        hydra_experiment()  # reads sys.argv
        return 0
    rest = [arg for arg in argv if arg not in actions]
    target = None
    if rest[:1] == ["--target"] and len(rest) == 2:
        target, rest = rest[1], []
    if len(actions) > 1 or rest:
        print(USAGE, file=sys.stderr)
        return 2
    try:
        if actions[0] == "--install-plugin":
            print(
                f"installed {install_plugin(target)}: python -m benchmarl.run ... task=fxc/<task> now finds the tasks"
            )
        else:
            path = uninstall_plugin(target)
            print(f"removed {path}" if path else "no plugin installed there")
    except ArgumentError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
