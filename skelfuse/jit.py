"""numba: the one lookup of it and the one compile setting, for every layer.

Fusion's hot stages are loops compiled with :func:`jit` (one implementation each: numba is a
dependency wherever fusion runs, :func:`require_fusion_dependencies`); the agent's depth
re-projection (:mod:`skelfuse.agent.reproject_raster`) compiles with it too, where numba is
optional (the ``fast`` extra) and :func:`jit` leaves a function as it is without it.
``NUMBA_DISABLE_JIT=1`` runs every loop as the Python it is written in, to debug it.
:func:`plain` gives a loop's arguments the types its warm-up compiled for.

Like :mod:`skelfuse.blas`, this module is in the bottom layer (it imports nothing of skelfuse),
so the agent may use it without importing :mod:`skelfuse.fusion`.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

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


def jit_inline(function: F) -> F:
    """:func:`jit` for a small helper of other kernels, inlined into each caller by numba
    itself (``inline="always"``): a call LLVM leaves out of line costs ~10 % in a per-view
    loop (the body frame: 48 views 17.9 → 19.4 µs). ``function`` itself without numba."""
    numba = numba_module()
    if numba is None:
        return function
    compiled: F = numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")(function)
    return compiled


def plain(array: npt.ArrayLike, dtype: type = np.float64) -> Any:
    """``array`` as a writable C-contiguous array of ``dtype`` (copied only when it is not):
    every call then has the argument types the warm-up compiled for, so no frame waits for a
    second compilation (a read-only or strided array is another numba signature).

    A read-only array that owns its data (the shared index tables and layouts: their values
    never change) is copied once and the copy kept with it; the kernels only read such
    arguments."""
    if isinstance(array, np.ndarray) and array.dtype == dtype and array.flags.c_contiguous:
        # The usual cases, without np.require's cost (several µs a call): as it is, or a copy
        # of a read-only array.
        if array.flags.writeable:
            return array
        if array.base is not None:  # a read-only view: its base may change, copy each time
            return array.copy()
        kept = _copies.get(id(array))
        if kept is None or kept[0] is not array:
            if len(_copies) >= _COPIES_KEPT:
                _copies.clear()
            kept = _copies[id(array)] = (array, array.copy())
        return kept[1]
    return np.require(array, dtype=dtype, requirements=("C", "W"))


_COPIES_KEPT = 256
_copies: dict[int, tuple[npt.NDArray[Any], npt.NDArray[Any]]] = {}
"""Writable copies of read-only arrays that own their data, by the original's id (the original
kept, so that its id is not reused meanwhile)."""
