"""numba, when installed: the one lookup of it and the one compile setting, for every layer.

numba is optional (the ``fast`` extra): :func:`numba_module` looks it up once per process and
:func:`jit` leaves a function as it is without it. The fusion kernels
(:mod:`skelfuse.fusion.kernels_jit`) and the agent's depth re-projection
(:mod:`skelfuse.agent.reproject_raster`) both compile with :func:`jit`; whether the fusion
kernels run at all is :mod:`skelfuse.fusion.kernels`' decision (``SKELFUSE_KERNELS``).

Like :mod:`skelfuse.blas`, this module sits below the layers (it imports nothing of skelfuse),
so the agent may use it without importing :mod:`skelfuse.fusion`.
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


def require_fusion_dependencies() -> None:
    """Return when numba and numpy 2 are importable, as fusion needs them.

    Raises:
        ImportError: naming what is missing and the install that brings it (the ``fusion``
            extra, part of ``server``).
    """
    import numpy as np

    missing = []
    if numba_module() is None:
        missing.append("numba (not installed)")
    if int(np.__version__.split(".")[0]) < 2:
        missing.append(f"numpy 2 (this environment has numpy {np.__version__})")
    if missing:
        raise ImportError(
            f"skelfuse's fusion needs {' and '.join(missing)}: install it with "
            "pip install 'skelfuse[fusion]' (the server extra includes it); the mono source's "
            "environment (numpy<2) runs the agent only"
        )


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
