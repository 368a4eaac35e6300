"""``python -m fxc_env.cli``: the ``fxc`` command."""

from __future__ import annotations

import sys

import numpy as np

from fxc_env.cli.main import main

np.set_printoptions(precision=6)
sys.exit(main())
