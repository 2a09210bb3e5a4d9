"""numba, when installed: the one place that imports it, and the decorator the kernels use.

numba is optional (the ``fast`` extra): :func:`numba_module` looks it up once, and :func:`jit`
leaves a function as it is without it. :mod:`skelfuse.fusion.kernels` decides whether the
compiled functions run at all.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

_found: dict[str, Any] = {}


def numba_module() -> Any | None:
    """The numba module, or None when it is not installed (looked up once per process)."""
    if "numba" not in _found:
        try:
            _found["numba"] = importlib.import_module("numba")
        except ImportError:
            _found["numba"] = None
    return _found["numba"]


def jit(function: F) -> F:
    """``function`` for numba's nopython mode, or ``function`` itself without numba.

    Compiled at its first call and cached on disk (``cache=True``: ``__pycache__`` beside the
    module, or ``NUMBA_CACHE_DIR``). ``error_model="numpy"``: a division by zero gives inf or
    NaN as in numpy, not Python's ZeroDivisionError. No ``fastmath``: the kernels must keep
    IEEE semantics and the order of operations to give numpy's bits.
    """
    numba = numba_module()
    if numba is None:
        return function
    compiled: F = numba.njit(cache=True, nogil=True, error_model="numpy")(function)
    return compiled
