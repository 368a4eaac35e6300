"""What every training back end shares about its run: the newest checkpoint, and a Ctrl-C that saves.

Checkpoints are files or directories named with their step count (``model_<timesteps>_steps.zip``
for SB3, ``model_<timesteps>_steps.pt`` for the torch back end, ``rllib_<timesteps>_steps/`` for
RLlib); Ctrl-C during training finishes the unit of work under way (an SB3 update, a torch
rollout, an RLlib iteration), saves a checkpoint and stops.
"""

from __future__ import annotations

import re
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


def newest_by_steps(directory: Path, glob: str, pattern: re.Pattern[str]) -> Path | None:
    """The entry of ``directory`` matching ``glob`` whose ``pattern`` group 1 (its step count) is largest."""
    found = [(int(match.group(1)), path) for path in directory.glob(glob) if (match := pattern.search(path.name))]
    return max(found)[1] if found else None


@contextmanager
def deferred_interrupt(unit: str) -> Iterator[list[bool]]:
    """Ctrl-C sets a flag (checked between ``unit``s) instead of breaking one; twice stops at once."""
    pressed: list[bool] = []
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        if pressed:
            raise KeyboardInterrupt
        pressed.append(True)
        print(f"\nfxc train: Ctrl-C; finishing this {unit}, then saving a checkpoint", file=sys.stderr)

    try:
        signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread: leave Ctrl-C alone
        yield pressed
        return
    try:
        yield pressed
    finally:
        signal.signal(signal.SIGINT, previous)
