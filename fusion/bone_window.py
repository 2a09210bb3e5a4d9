"""The last ``window`` bone-length observations of one person, and their per-bone median.

What :class:`skelfuse.fusion.bones.BoneModel` estimates from. Stored bones first in a ring,
(24, window), NaN where nothing was observed: appending overwrites the oldest observation, as
a ``deque(maxlen=window)`` drops it, and the median sorts contiguous rows. A median does not
depend on the order of its observations, so it is, to the bit, the median of the same
observations in arrival order.

Shapes: 24 bones in :data:`skelfuse.protocol.skeleton.BONES` order; metres.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_median
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
"""No second row per bone (:func:`~skelfuse.fusion.kernels_median.window_medians`)."""


def nanmedian_axis(data: FloatArray, axis: int) -> FloatArray:
    """``np.nanmedian`` along ``axis`` (the same values: mean of the two middle ones), faster.

    All-NaN slices give NaN without a warning.
    """
    moved = np.moveaxis(data, axis, -1)
    if moved.shape[-1] == 0:
        return np.full(moved.shape[:-1], np.nan)
    return nanmedian_last(moved)  # its sort copies the moved axis into contiguous rows


def nanmedian_last(data: FloatArray) -> FloatArray:
    """:func:`nanmedian_axis` along the last axis (the same values), on its contiguous rows
    without moving axes: (..., n) → (...), n ≥ 1."""
    n = data.shape[-1]
    if kernels.enabled() and kernels_median.warmed():  # the same bits by selection, no sort
        return kernels_median.row_medians(data.reshape(-1, n)).reshape(data.shape[:-1])
    rows = np.sort(data, axis=-1).reshape(-1, n)  # NaN last
    count = np.isfinite(rows).sum(axis=1)
    # The middle two of each row's finite values, by their flat index.
    first = np.arange(0, rows.size, n)
    flat = rows.reshape(-1)
    low = flat[first + np.maximum((count - 1) // 2, 0)]
    high = flat[first + count // 2]
    median: FloatArray = np.where(count > 0, (low + high) / 2.0, np.nan)
    return median.reshape(data.shape[:-1])


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
        if kernels.enabled() and kernels_median.warmed():  # the same bits in one call
            second = _MIRROR_OF_PAIRS if symmetric else _NO_ROWS
            median, counts = kernels_median.window_medians(
                self._data, self._size, _PAIRS if symmetric else _BONES, second, min_samples
            )
            return (median[_PAIR_OF], counts[_PAIR_OF]) if symmetric else (median, counts)
        data = self._data[:, : self._size]
        if not symmetric:
            counts = np.isfinite(data).sum(axis=1) / 1
            return np.where(counts >= min_samples, nanmedian_axis(data, 1), np.nan), counts
        # Both bones of a pair pool the same observations: one median per pair serves both.
        pooled = np.concatenate([data[_PAIRS], data[BONE_MIRROR[_PAIRS]]], axis=1)
        counts = np.isfinite(pooled).sum(axis=1) / 2
        median = np.where(counts >= min_samples, nanmedian_axis(pooled, 1), np.nan)
        return median[_PAIR_OF], counts[_PAIR_OF]
