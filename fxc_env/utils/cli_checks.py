"""Checks of ``fxc`` command-line values, made before a subcommand starts work.

Each check names the flag (``--out``, ``--n-envs``, ...) and says what was expected; it
raises :class:`fxc_env.core.validation.ArgumentError`, the usage error that
:func:`fxc_env.cli.main` prints as one line (exit status 2). Nothing here writes: a
subcommand checks all of its values first, then creates its directories.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from fxc_env.core.validation import MAX_INTERVALS, ArgumentError

__all__ = ["budgets", "output_directory", "yaml_mapping_file"]


def output_directory(flag: str, value: str | os.PathLike[str]) -> Path:
    """A directory the command may write into (created later, with its parents, like ``mkdir -p``).

    Refused, naming ``flag``: an empty path, an existing path that is not a directory, a
    path below a file (``notes.txt/out``), and a directory this process may not write into
    or create (by ``os.access``; root passes that test wherever the file system allows).
    """
    text = os.fspath(value)
    if not text.strip():
        raise ArgumentError(f"{flag}: expected a directory path, got {text!r}")
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise ArgumentError(f"{flag}: expected a directory, got {text!r}, which is an existing file")
    existing = path.absolute()
    while not existing.exists():  # the nearest ancestor that exists: mkdir -p starts there
        if existing.is_symlink():
            raise ArgumentError(f"{flag}: cannot create {text!r}: {str(existing)!r} is a dangling symbolic link")
        existing = existing.parent
    if not existing.is_dir():
        raise ArgumentError(f"{flag}: cannot create {text!r}: {str(existing)!r} is a file, not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "write into" if existing == path.absolute() else "create directories in"
        raise ArgumentError(f"{flag}: cannot {what} {str(existing)!r} (permission denied)")
    return path


def yaml_mapping_file(flag: str, value: str | os.PathLike[str]) -> dict[Any, Any]:
    """The mapping a YAML file holds; a missing, unreadable or malformed file is refused naming ``flag``."""
    path = Path(value)
    if not path.is_file():
        why = "is a directory" if path.is_dir() else "does not exist"
        raise ArgumentError(f"{flag}: expected a YAML file, got {str(value)!r}, which {why}")
    try:
        table = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise ArgumentError(f"{flag}: cannot read {str(value)!r} ({exc})") from exc
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ArgumentError(f"{flag}: {str(value)!r} is not valid YAML ({first})") from exc
    if not isinstance(table, dict):
        raise ArgumentError(f"{flag}: expected a YAML mapping in {str(value)!r}, got {type(table).__name__}")
    return table


def budgets(flag: str, text: str) -> tuple[int, ...]:
    """Comma-separated budgets K, each an integer in ``[1, MAX_INTERVALS]``, no repeats: ``"25,200"``."""
    expected = f"comma-separated integers in [1, {MAX_INTERVALS:g}]"
    parts = [part.strip() for part in str(text).split(",")]
    try:
        values = tuple(int(part) for part in parts)
    except ValueError:
        raise ArgumentError(f"{flag}: expected {expected}, got {text!r}") from None
    if any(not 1 <= k <= MAX_INTERVALS for k in values):
        raise ArgumentError(f"{flag}: expected {expected}, got {text!r}")
    if len(set(values)) != len(values):
        raise ArgumentError(f"{flag}: expected distinct budgets, got {text!r}")
    return values
