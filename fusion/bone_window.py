"""The last ``window`` bone-length observations of one person, and their per-bone median.

What :class:`skelfuse.fusion.bones.BoneModel` estimates from. Stored bones first in a ring,
(24, window), NaN where nothing was observed: appending overwrites the oldest observation, as
a ``deque(maxlen=window)`` drops it. A median does not depend on the order of its
observations, so it is, to the bit, the median of the same observations in arrival order.

The medians are compiled loops that find each row's two middle values by selection (Hoare's,
middle pivot) rather than a full sort: the values a sort would put in those places. The rule is
np.nanmedian's with its corners kept: the count is of finite values, the two middle places are
taken among the values that are not NaN (infinities sort among them), and a row without a
finite value gives NaN. :meth:`SampleWindow.median` reads each row where the ring keeps it (a
left bone's and its right counterpart's together), with no pooled copy.

Shapes: 24 bones in :data:`skelfuse.protocol.skeleton.BONES` order; metres.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.jit import jit, plain
from skelfuse.protocol.skeleton import BONE_MIRROR_PERMUTATION, BONES

FloatArray = npt.NDArray[np.float64]
BONE_COUNT: Final = len(BONES)
BONE_MIRROR: Final = np.array(BONE_MIRROR_PERMUTATION)
_PAIRS: Final = np.array(sorted({min(b, int(m)) for b, m in enumerate(BONE_MIRROR)}))
"""One bone of each left/right pair (midline bones are their own pair)."""
_PAIR_OF: Final = np.searchsorted(_PAIRS, np.minimum(np.arange(BONE_COUNT), BONE_MIRROR))
"""Per bone, its pair's row among :data:`_PAIRS`."""
_MIRROR_OF_PAIRS: Final = BONE_MIRROR[_PAIRS]
"""Each pair's other bone (a midline bone: itself, read twice as numpy's pooling does)."""
_BONES: Final = np.arange(BONE_COUNT)
_NO_ROWS: Final = np.full(BONE_COUNT, -1)
"""No second row per bone (:func:`window_medians`)."""


def nanmedian_axis(data: FloatArray, axis: int) -> FloatArray:
    """``np.nanmedian`` along ``axis`` (the same values: mean of the two middle ones), faster.

    All-NaN (or empty) slices give NaN without a warning.
    """
    return nanmedian_last(np.moveaxis(data, axis, -1))  # plain() copies it into contiguous rows


def nanmedian_last(data: FloatArray) -> FloatArray:
    """:func:`nanmedian_axis` along the last axis (the same values), on its contiguous rows
    without moving axes: (..., n) → (...)."""
    rows = data.reshape(math.prod(data.shape[:-1]), data.shape[-1])
    out = np.empty(rows.shape[0])
    _medians_loop(plain(rows), out)
    return out.reshape(data.shape[:-1])


class SampleWindow:
    """The last ``window`` (24,) observations (module docstring)."""

    def __init__(self, window: int) -> None:
        self._data = np.full((BONE_COUNT, max(window, 0)), np.nan)
        self._window = max(window, 0)
        self._size = 0
        self._next = 0

    def __len__(self) -> int:
        return self._size

    def append(self, lengths: FloatArray) -> None:
        """Add one observation, (24,) metres (NaN: bone not observed), dropping the oldest."""
        window = self._window
        if window == 0:
            return
        self._data[:, self._next] = lengths
        self._next = (self._next + 1) % window
        if self._size < window:
            self._size += 1

    def mirror(self) -> None:
        """Swap left and right bones in every observation."""
        self._data = self._data[BONE_MIRROR]

    def median(self, min_samples: int, symmetric: bool) -> tuple[FloatArray, FloatArray]:
        """Per-bone median (NaN where fewer than ``min_samples`` observations) and the number
        of observations behind it, (24,) each. With ``symmetric`` a left bone and its right
        counterpart pool their observations (the count is the mean of the two sides')."""
        if not self._size:
            return np.full(BONE_COUNT, np.nan), np.zeros(BONE_COUNT)
        second = _MIRROR_OF_PAIRS if symmetric else _NO_ROWS
        median, counts = window_medians(
            self._data, self._size, _PAIRS if symmetric else _BONES, second, min_samples
        )
        # Both bones of a pair pool the same observations: one median per pair serves both.
        return (median[_PAIR_OF], counts[_PAIR_OF]) if symmetric else (median, counts)


def warm_up() -> None:
    """Compile (or load from numba's cache) the loops now, off any latency-bound path."""
    nanmedian_last(np.zeros((1, 2)))
    rows = np.zeros(1, np.intp)
    window_medians(np.zeros((1, 2)), 1, rows, rows, 1)
    window_medians(np.zeros((1, 2)), 1, rows, np.full(1, -1, np.intp), 1)


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
    read (1 or 2), and the median of their finite values (:func:`nanmedian_last`'s rule on
    their concatenation), NaN where that count is below ``min_samples``.

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
def _medians_loop(rows: FloatArray, out: FloatArray) -> None:
    """:func:`nanmedian_last` of ``rows`` (R, n) into ``out`` (R,)."""
    n = rows.shape[1]
    values = np.empty(n)
    for r in range(rows.shape[0]):
        kept, finite = _collect(rows[r], n, values, 0, 0)
        out[r] = _middle(values, kept, finite)


@jit
def _window_loop(
    window: FloatArray,
    size: int,
    first: npt.NDArray[np.intp],
    second: npt.NDArray[np.intp],
    min_samples: int,
    medians: FloatArray,
    counts: FloatArray,
) -> None:
    """:func:`window_medians` into ``medians`` and ``counts``."""
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
def _collect(
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
def _middle(values: FloatArray, kept: int, finite: int) -> float:
    """The median of ``values[:kept]`` by :func:`nanmedian_last`'s rule (``finite`` of them
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
def _select(values: FloatArray, count: int, k: int) -> float:
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
