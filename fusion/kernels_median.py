"""Row medians of the online bone-length window as one compiled loop (numba).

:meth:`skelfuse.fusion.bone_window.SampleWindow.median` takes, every ten steps per person, the
median of each bone pair's last 600 observations: in numpy a sort of the (14, 600) window and
a few gathers, 90 µs of the refresh's 140–210, and a step where six persons refresh together
pays it six times. Here each row's two middle values are found by selection instead of a
full sort: the values are the ones the sort puts in those places, so the medians are the same
bits (tests/unit/test_kernels_median.py); 41–47 µs (the whole refresh 107–137 µs, measured
interleaved on one window at 2026-11-23 22:10).

The rule is :func:`~skelfuse.fusion.bone_window.nanmedian_last`'s, including its corners: the
count is of finite values, the two middle places are taken among the values that are not NaN
(NaN sorts last), and a row without a finite value gives NaN.

As :mod:`skelfuse.fusion.kernels_observe`: the loop runs only once :func:`warm_up` has compiled
it, so no frame waits for a compilation; until then, and with the kernels off, numpy runs.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import Warmed, jit, plain

FloatArray = npt.NDArray[np.float64]

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now; a no-op with the kernels off."""
    row_medians(np.zeros((1, 2)))
    warmed.done = True


def row_medians(rows: FloatArray) -> FloatArray:
    """Each row's median of its finite values, (R, n) metres → (R,) float64 (n ≥ 1): the mean
    of the two middle values, NaN for a row with none."""
    out = np.empty(rows.shape[0])
    _medians_loop(plain(rows), out)
    return out


@jit
def _medians_loop(rows: FloatArray, out: FloatArray) -> None:  # pragma: no cover - compiled
    n = rows.shape[1]
    values = np.empty(n)
    for r in range(rows.shape[0]):
        kept = 0  # values that are not NaN (infinities sort among them, as in np.sort)
        finite = 0
        for i in range(n):
            v = rows[r, i]
            if v == v:
                values[kept] = v
                kept += 1
                if np.isfinite(v):
                    finite += 1
        if finite == 0:
            out[r] = np.nan
            continue
        high_at = finite // 2
        low_at = (finite - 1) // 2
        high = _select(values, kept, high_at)
        low = high
        if low_at < high_at:  # the largest of the values left below the high one
            low = values[0]
            for i in range(1, high_at):
                if values[i] > low:
                    low = values[i]
        out[r] = (low + high) / 2.0


@jit
def _select(values: FloatArray, count: int, k: int) -> float:  # pragma: no cover - compiled
    """The ``k``-th smallest of ``values[:count]`` (no NaN), leaving every smaller one before
    place ``k`` and every larger one after it (Hoare's selection, middle pivot)."""
    lo, hi = 0, count - 1
    while lo < hi:
        pivot = values[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return float(values[k])
