"""numba, when installed: the decorators the kernels use.

numba is optional (the ``fast`` extra): :func:`numba_module` looks it up once, and :func:`jit`
leaves a function as it is without it (both from :mod:`skelfuse.jit`, shared with the agent).
:mod:`skelfuse.fusion.kernels` decides whether the compiled functions run at all.
:func:`plain` gives the kernels' arguments the types their warm-up compiled for;
:class:`Warmed` records that a module's warm-up has run.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from skelfuse.jit import jit as jit, numba_module as numba_module

F = TypeVar("F", bound=Callable[..., Any])


class Warmed:
    """Whether a module's ``warm_up()`` has compiled its loops (or loaded them from numba's
    cache): call it to know. Callers use the loops only then, and only when
    :func:`skelfuse.fusion.kernels.enabled`, so no frame waits for a compilation (the kernel
    modules do not import that one, which warms them up)."""

    __slots__ = ("done",)

    def __init__(self) -> None:
        self.done = False
        """Set by the module's ``warm_up()`` once it has called every loop."""

    def __call__(self) -> bool:
        """Whether the warm-up has run."""
        return self.done


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


def in_place(array: npt.NDArray[Any], dtype: type) -> bool:
    """Whether a kernel can write ``array`` in place as it is: C-ordered, writable, ``dtype``
    (what :func:`plain` returns unchanged)."""
    return bool(array.dtype == dtype and array.flags.c_contiguous and array.flags.writeable)


_COPIES_KEPT = 256
_copies: dict[int, tuple[npt.NDArray[Any], npt.NDArray[Any]]] = {}
"""Writable copies of read-only arrays that own their data, by the original's id (the original
kept, so that its id is not reused meanwhile)."""
