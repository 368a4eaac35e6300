"""``python -m fxc_env.speed [options]``: ``fxc speed`` without the rest of the ``fxc`` command."""

from __future__ import annotations

import sys

from fxc_env.speed.command import main

if __name__ == "__main__":
    sys.exit(main())
