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

:func:`window_medians` does the whole of ``SampleWindow.median`` in one call: each row's values
read where the window keeps them (a left bone's and its right counterpart's together), counted
and their median selected, with no pooled copy of the window, no count pass and no masks in
numpy between them (75 → 34 µs a person on one 300-sample window, 2026-11-24 15:01; six
persons refresh together).

As the other kernel modules: the loop runs only once :func:`warm_up` has compiled
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
    """Compile (or load from numba's cache) the loops now; a no-op with the kernels off."""
    row_medians(np.zeros((1, 2)))
    rows = np.zeros(1, np.intp)
    window_medians(np.zeros((1, 2)), 1, rows, rows, 1)
    window_medians(np.zeros((1, 2)), 1, rows, np.full(1, -1, np.intp), 1)
    warmed.done = True


def row_medians(rows: FloatArray) -> FloatArray:
    """Each row's median of its finite values, (R, n) metres → (R,) float64 (n ≥ 1): the mean
    of the two middle values, NaN for a row with none."""
    out = np.empty(rows.shape[0])
    _medians_loop(plain(rows), out)
    return out


def window_medians(
    window: FloatArray,
    size: int,
    first: npt.NDArray[np.intp],
    second: npt.NDArray[np.intp],
    min_samples: int,
) -> tuple[FloatArray, FloatArray]:
    """``SampleWindow.median``'s answer from the window itself: per output row ``r``, the
    values of ``window[first[r], :size]`` and, unless ``second[r]`` is −1, of
    ``window[second[r], :size]`` together; their finite count divided by the number of rows
    read (1 or 2), and the median of their finite values (:func:`row_medians`' rule on their
    concatenation: a median does not depend on the values' order, so the same bits), NaN
    where that count is below ``min_samples``.

    Args:
        window: (B, W) metres, NaN where nothing was observed; size: the columns in use
            (1 ≤ size ≤ W); first, second: (R,) rows of ``window`` (second: −1 for none).

    Returns:
        (R,) medians and (R,) counts, float64.
    """
    medians = np.empty(first.shape[0])
    counts = np.empty(first.shape[0])
    _window_loop(
        plain(window), int(size), plain(first, np.intp), plain(second, np.intp),
        int(min_samples), medians, counts,
    )  # fmt: skip
    return medians, counts


@jit
def _medians_loop(rows: FloatArray, out: FloatArray) -> None:  # pragma: no cover - compiled
    n = rows.shape[1]
    values = np.empty(n)
    for r in range(rows.shape[0]):
        kept, finite = _collect(rows[r], n, values, 0, 0)
        out[r] = _middle(values, kept, finite)


@jit
def _window_loop(  # pragma: no cover - compiled
    window: FloatArray,
    size: int,
    first: npt.NDArray[np.intp],
    second: npt.NDArray[np.intp],
    min_samples: int,
    medians: FloatArray,
    counts: FloatArray,
) -> None:
    values = np.empty(2 * size)
    for r in range(first.shape[0]):
        kept, finite = _collect(window[first[r]], size, values, 0, 0)
        read = 1
        if second[r] >= 0:
            kept, finite = _collect(window[second[r]], size, values, kept, finite)
            read = 2
        counts[r] = finite / read
        if counts[r] >= min_samples:
            medians[r] = _middle(values, kept, finite)
        else:
            medians[r] = np.nan


@jit
def _collect(  # pragma: no cover - compiled
    row: FloatArray, n: int, values: FloatArray, kept: int, finite: int
) -> tuple[int, int]:
    """``row[:n]``'s values that are not NaN appended to ``values`` after its first ``kept``
    (infinities sort among them, as in np.sort); the new ``kept`` and finite counts."""
    for i in range(n):
        v = row[i]
        if v == v:
            values[kept] = v
            kept += 1
            if np.isfinite(v):
                finite += 1
    return kept, finite


@jit
def _middle(values: FloatArray, kept: int, finite: int) -> float:  # pragma: no cover - compiled
    """The median of ``values[:kept]`` by :func:`row_medians`' rule (``finite`` of them
    finite; NaN for none); reorders them."""
    if finite == 0:
        return np.nan
    high_at = finite // 2
    low_at = (finite - 1) // 2
    high = _select(values, kept, high_at)
    low = high
    if low_at < high_at:  # the largest of the values left below the high one
        low = values[0]
        for i in range(1, high_at):
            if values[i] > low:
                low = values[i]
    return (low + high) / 2.0


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
