"""One namespace for numpy arrays and torch tensors: the Python array API standard.

The core maths and the engine are written against the array API (``xp.where``, ``xp.max``,
``xp.clip``, ...) so that the same lines run on numpy arrays and on torch tensors on any
device; :func:`namespace` returns the standard-conforming namespace of its arguments
(``array-api-compat`` wraps numpy and torch alike, and never imports torch itself).
Backend-specific fast paths are allowed only where a measurement shows they pay, and sit
next to the generic lines they replace (see :mod:`fxc_env.engine`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from array_api_compat import array_namespace, is_numpy_namespace

__all__ = ["is_numpy", "namespace"]


def namespace(*arrays: Any) -> Any:
    """The array API namespace of ``arrays`` (python scalars are ignored; numpy if there is no array)."""
    arrays = tuple(a for a in arrays if not isinstance(a, int | float | bool) and a is not None)
    return array_namespace(*arrays) if arrays else array_namespace(np.empty(0))


def is_numpy(xp: Any) -> bool:
    """Whether ``xp`` is numpy's namespace (where numpy-only fast paths apply)."""
    return is_numpy_namespace(xp)
