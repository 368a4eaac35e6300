"""BenchMARL's command line for fxc_env's tasks (docs: tutorials/benchmarl.md, "Tutorial: BenchMARL").

Two routes to the same run::

    python -m fxc_env.envs.benchmarl_run --install-plugin  # once per environment, then
    python -m benchmarl.run algorithm=mappo task=fxc/rings20-v1 "experiment.loggers=[csv]"  # BenchMARL's own

    python -m fxc_env.envs.benchmarl_run algorithm=mappo task=fxc/rings20-v1 "experiment.loggers=[csv]"  # no plugin

(BenchMARL's default loggers add wandb, which it does not require: docs tutorials/benchmarl.md.)

``--install-plugin`` copies :mod:`fxc_env.envs.benchmarl_plugin` to
``hydra_plugins/fxc_env_benchmarl.py`` in this interpreter's site-packages (or ``--target DIR``), the one
place Hydra looks for another package's code, with a last line holding the SHA-256 of the rest (so an
edited copy is refused by name, never replaced); ``--uninstall-plugin`` removes an unedited copy. Without it, this
module takes every argument of ``python -m benchmarl.run`` (Hydra overrides, ``--multirun``) and runs
BenchMARL's own ``hydra_experiment`` after :func:`fxc_env.envs.benchmarl_task.register`.
"""

from __future__ import annotations

import hashlib
import sys
import sysconfig
from pathlib import Path

from fxc_env.core.validation import ArgumentError

#: Where the plugin goes, under the target folder (a module of Hydra's ``hydra_plugins`` namespace).
PLUGIN_PATH = Path("hydra_plugins", "fxc_env_benchmarl.py")
#: The plugin's source: this package's module, copied with :data:`MARK` as its last line.
PLUGIN_SOURCE = Path(__file__).with_name("benchmarl_plugin.py")
#: The start of an installed copy's last line, which ends with the SHA-256 (hex) of every line above it:
#: a copy edited since it was installed no longer matches, and is neither replaced nor removed.
MARK = "# fxc_env BenchMARL plugin, SHA-256 of the lines above: "
#: SHA-256 of the copies installed, verbatim and without :data:`MARK`, before copies were marked (2d0bd5c).
UNMARKED_COPIES = frozenset({"2632d808e8b4f1fe778a981d7fe07701414588e232a0a6cdbf182e2059ccfe63"})
USAGE = (
    "usage: python -m fxc_env.envs.benchmarl_run (--install-plugin | --uninstall-plugin) [--target DIR]\n"
    "       python -m fxc_env.envs.benchmarl_run [python -m benchmarl.run's arguments]"
)


def install_plugin(target: str | Path | None = None) -> Path:
    """Write the plugin to ``<target>/hydra_plugins/fxc_env_benchmarl.py`` and return its path.

    ``target`` defaults to this interpreter's site-packages (``sysconfig``'s ``purelib``). The copy
    is the plugin's source and a last line holding the SHA-256 of everything above it
    (:func:`plugin_text`). A file already there is replaced only if it is such a copy, unedited (or
    an unmarked copy of a release before the mark); anything else, a symbolic link included, is
    refused by name and left as it is.
    """
    path = _plugin_path(target)
    _check_ours(path, "nothing was written")
    if path.parent.exists() and not path.parent.is_dir():
        raise ArgumentError(f"target: {path.parent} is not a folder; nothing was written")
    path.parent.mkdir(exist_ok=True)  # a namespace package: no __init__.py
    path.write_text(plugin_text())
    return path


def uninstall_plugin(target: str | Path | None = None) -> Path | None:
    """Remove the plugin written by :func:`install_plugin`; return its path, or ``None`` if none was there.

    A file there that is not an unedited copy (a copy edited since, another file, a symbolic link)
    is refused by name and left as it is.
    """
    path = _plugin_path(target)
    if not path.exists() and not path.is_symlink():
        return None
    _check_ours(path, "nothing was removed")
    path.unlink()
    if not any(path.parent.iterdir()):
        path.parent.rmdir()
    return path


def plugin_text() -> str:
    """What :func:`install_plugin` writes: the plugin's source, then :data:`MARK` and the source's SHA-256."""
    source = PLUGIN_SOURCE.read_text()
    return f"{source}{MARK}{_sha256(source)}\n"


def on_sys_path(folder: str | Path) -> bool:
    """Whether ``folder`` is on this interpreter's ``sys.path`` (its current folder, ``''``, aside)."""
    entries = {Path(entry).resolve() for entry in sys.path if entry and Path(entry).resolve() != Path.cwd()}
    return Path(folder).resolve() in entries


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _check_ours(path: Path, nothing_done: str) -> None:
    """Refuse, naming ``target``, unless ``path`` is absent or an unedited copy that :func:`install_plugin` wrote."""
    if path.is_symlink():
        raise ArgumentError(f"target: {path} is a symbolic link, not a copy fxc_env wrote; {nothing_done}")
    if not path.exists():
        return
    if not path.is_file():
        raise ArgumentError(f"target: {path} is not fxc_env's BenchMARL plugin (not a file); {nothing_done}")
    text = path.read_bytes().decode(errors="replace")
    body, _, last = text.removesuffix("\n").rpartition("\n")
    if MARK in text:
        if last.startswith(MARK) and _sha256(body + "\n") == last.removeprefix(MARK):
            return
        raise ArgumentError(
            f"target: {path} is fxc_env's BenchMARL plugin edited since it was installed (it no longer matches "
            f"the SHA-256 on its last line); {nothing_done}: keep your edits elsewhere, or remove it yourself"
        )
    if _sha256(text) not in UNMARKED_COPIES:
        raise ArgumentError(f"target: {path} exists and is not fxc_env's BenchMARL plugin; {nothing_done}")


def _plugin_path(target: str | Path | None) -> Path:
    if isinstance(target, str) and not target.strip():  # Path("") would be the current folder
        raise ArgumentError(f"target: expected an existing folder on sys.path (site-packages), got {target!r}")
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
            path = install_plugin(target)
            found = on_sys_path(path.parents[1])
            print(f"installed {path}" + (": python -m benchmarl.run ... task=fxc/<task> now finds the tasks" * found))
            if not found:
                print(
                    f"warning: target: {path.parents[1]} is not on this interpreter's sys.path: "
                    "python -m benchmarl.run finds the tasks only where it is (PYTHONPATH, a .pth file)",
                    file=sys.stderr,
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
