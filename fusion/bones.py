"""Bone lengths: each person's reference lengths, set by hand or estimated online from the
views (per person and bone, the median length its views show, in one compiled loop), and the fit
that gives a fused skeleton those lengths (:mod:`skelfuse.fusion.bone_fit`).

What :class:`BoneModel` estimates from (:class:`SampleWindow`, last section): the last
``window`` bone-length observations of one person, stored bones first in a ring, (24, window),
NaN where nothing was observed: appending overwrites the oldest observation, as a
``deque(maxlen=window)`` drops it. A median does not depend on the order of its observations, so
it is, to the bit, the median of the same observations in arrival order. The medians are
compiled loops that find each row's two middle values by selection (Hoare's, middle pivot)
rather than a full sort: the values a sort would put in those places. The rule is np.nanmedian's
with its corners kept: the count is of finite values, the two middle places are taken among the
values that are not NaN (infinities sort among them), and a row without a finite value gives
NaN. :meth:`SampleWindow.median` reads each row where the ring keeps it (a left bone's and its
right counterpart's together), with no pooled copy.

Shapes: 25 joints, 24 bones in :data:`skelfuse.protocol.skeleton.BONES` order; metres.
"""

from __future__ import annotations

import math
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.bone_fit import (
    BONE_CHILD,
    BONE_COUNT,
    BONE_PARENT,
)
from skelfuse.jit import jit, jit_inline, plain
from skelfuse.protocol.skeleton import BONE_MIRROR_PERMUTATION, TrackingState

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
_TRACKED: Final = int(TrackingState.TRACKED)
GOOD_VIEW_COS: Final = 0.5
"""A view feeds the online bone-length estimate only if the person faces it within 60°."""

BoneSource = Literal["set", "estimated", "none"]


class BoneModel:
    """A person's reference bone lengths: set by hand, or estimated online.

    The online estimate is, per bone, the median of the last ``window`` observations from good
    views (both ends Tracked, the person facing the sensor within 60°, after mirror
    correction). A bone that good views have not shown ``min_samples`` times yet (hand tips and
    thumbs, often) takes the median of any view where both ends are Tracked instead. With
    ``symmetric``, a left bone and its right counterpart share their observations: people are
    left-right symmetric to a percent or two, and twice the samples settle the estimate sooner.
    The estimate is refreshed every step while it settles, then every ``_REFRESH_EVERY`` steps.
    """

    _REFRESH_EVERY = 10

    def __init__(
        self,
        window: int = 300,
        min_samples: int = 30,
        symmetric: bool = True,
        lock_samples: int | None = None,
    ) -> None:
        self.set_lengths: FloatArray | None = None
        self.min_samples = min_samples
        self.symmetric = symmetric
        self.lock_samples = lock_samples
        self._locked = np.zeros(BONE_COUNT, dtype=bool)
        self._samples = SampleWindow(window)
        self._fallback = SampleWindow(window)
        self._estimate = np.full(BONE_COUNT, np.nan)
        self._since_update = 0

    @property
    def source(self) -> BoneSource:
        if self.set_lengths is not None:
            return "set"
        return "estimated" if np.isfinite(self._estimate).any() else "none"

    @property
    def estimate(self) -> FloatArray:
        """(24,) online estimate, metres; NaN for bones without enough observations."""
        return self._estimate.copy()

    def reference(self) -> FloatArray:
        """(24,) the lengths fusion uses: the set ones, else the estimate (NaN: unknown)."""
        return self.set_lengths.copy() if self.set_lengths is not None else self.estimate

    def observe(self, lengths: FloatArray, fallback: FloatArray | None = None) -> None:
        """Add one step's observed lengths.

        Args:
            lengths: (24,) metres from good views, NaN for bones not observed well.
            fallback: (24,) metres from any view with both ends Tracked, or None.
        """
        good = bool(np.isfinite(lengths).any())
        spare = fallback is not None and bool(np.isfinite(fallback).any())
        self._add(lengths if good else None, fallback if spare else None)

    def _add(self, lengths: FloatArray | None, fallback: FloatArray | None) -> None:
        """:meth:`observe` once it is known which of the two hold any length (None: none)."""
        if lengths is None and fallback is None:
            return
        if lengths is not None:
            self._samples.append(lengths)
        if fallback is not None:
            self._fallback.append(fallback)
        self._since_update += 1
        settling = len(self._samples) < 2 * self.min_samples
        if settling or self._since_update >= self._REFRESH_EVERY:
            self._since_update = 0
            estimate, counts = self._samples.median(self.min_samples, self.symmetric)
            missing = ~np.isfinite(estimate)
            if missing.any():
                backup = self._fallback.median(self.min_samples, self.symmetric)[0]
                estimate[missing] = backup[missing]
            self._estimate = np.where(self._locked, self._estimate, estimate)
            if self.lock_samples is not None:
                self._locked |= counts >= self.lock_samples

    def mirror(self) -> None:
        """Swap left and right in the online samples (the track they came from was mirrored)."""
        self._samples.mirror()
        self._fallback.mirror()
        self._estimate = self._estimate[BONE_MIRROR]
        self._locked = self._locked[BONE_MIRROR]


def references_of(models: list[BoneModel]) -> FloatArray:
    """(P, 24) each model's :meth:`BoneModel.reference` (P >= 1), without a copy of each."""
    rows = [m.set_lengths if m.set_lengths is not None else m._estimate for m in models]
    return np.array(rows, dtype=np.float64)


def observe_bone_lengths(
    models: list[BoneModel],
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    cosines: FloatArray,
    person_of: npt.NDArray[np.intp],
    slot_of: npt.NDArray[np.intp],
    widest: int,
) -> None:
    """Feed each person's online estimate with this step's views of that person.

    Args:
        models: one per person (P).
        joints: (N, 25, 3) all persons' views, metres, labels corrected; states: (N, 25).
        cosines: (N,) each view's facing cosine: good views face their sensor within 60°.
        person_of: (N,) each view's person.
        slot_of, widest: unused (each view's index among its person's views, the most views
            any person has): the loop finds each person's views by ``person_of``.
    """
    estimating = [model.set_lengths is None for model in models]
    if not any(estimating):
        return
    per_bone = bone_medians(joints, states, cosines, person_of, len(models))
    # (persons, 2): whether any good view, and any view at all, shows some bone
    seen: list[list[bool]] = np.logical_or.reduce(np.isfinite(per_bone), axis=2).tolist()
    for p, ((good, spare), wanted) in enumerate(zip(seen, estimating, strict=True)):
        if spare and wanted:  # a person with no usable view at all adds nothing
            models[p]._add(per_bone[p, 0] if good else None, per_bone[p, 1])


def warm_up() -> None:
    """Compile (or load from numba's cache) the observation's and the window's loops now, off
    any latency-bound path."""
    index = np.zeros(1, dtype=np.intp)
    bone_medians(np.zeros((1, 25, 3)), np.zeros((1, 25), np.uint8), np.zeros(1), index, 1)
    nanmedian_last(np.zeros((1, 2)))
    rows = np.zeros(1, np.intp)
    window_medians(np.zeros((1, 2)), 1, rows, rows, 1)
    window_medians(np.zeros((1, 2)), 1, rows, np.full(1, -1, np.intp), 1)


def bone_medians(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    cosines: FloatArray,
    person_of: IntArray,
    persons: int,
) -> FloatArray:
    """Per person and bone, the median length over its good views and over all its views.

    A bone's length in a view counts when both its ends are Tracked and it is finite; a good
    view's facing cosine is finite and at least :data:`GOOD_VIEW_COS`. The median of an even
    count is the mean of the middle two.

    Args:
        joints: (N, 25, 3) every person's views, metres; states: (N, 25) tracking states;
            cosines: (N,) each view's facing cosine; person_of: (N,) each view's person,
            < ``persons``.

    Returns:
        (persons, 2, 24) float64 metres: [.., 0] good views, [.., 1] any view; NaN where no
        view shows the bone.
    """
    out = np.empty((persons, 2, BONE_COUNT))
    _medians_loop(
        plain(joints),
        plain(states, np.uint8),
        plain(cosines),
        plain(person_of, np.intp),
        plain(BONE_PARENT, np.intp),
        plain(BONE_CHILD, np.intp),
        _TRACKED,
        GOOD_VIEW_COS,
        out,
    )
    return out


@jit
def _medians_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    cosines: FloatArray,
    person_of: IntArray,
    parents: IntArray,
    children: IntArray,
    tracked: int,
    good_cos: float,
    out: FloatArray,
) -> None:
    """:func:`bone_medians` into ``out``: every view's bone lengths, then per person, kind and
    bone an insertion sort of the finite ones."""
    lengths = _view_lengths(joints, states, parents, children, tracked)
    views, bones = lengths.shape
    good = np.empty(views, dtype=np.bool_)
    for i in range(views):
        good[i] = np.isfinite(cosines[i]) and cosines[i] >= good_cos
    values = np.empty(max(views, 1))
    own = np.empty(max(views, 1), dtype=np.intp)  # the person's views, in their order
    for p in range(out.shape[0]):
        count_own = 0
        for i in range(views):
            if person_of[i] == p:
                own[count_own] = i
                count_own += 1
        for kind in range(2):
            for b in range(bones):
                count = 0
                for k in range(count_own):
                    i = own[k]
                    if kind == 0 and not good[i]:
                        continue
                    v = lengths[i, b]
                    if v != v:  # NaN: not shown
                        continue
                    j = count  # insertion into the sorted values so far
                    while j > 0 and values[j - 1] > v:
                        values[j] = values[j - 1]
                        j -= 1
                    values[j] = v
                    count += 1
                if count > 0:
                    out[p, kind, b] = (values[(count - 1) // 2] + values[count // 2]) / 2.0
                else:
                    out[p, kind, b] = np.nan


@jit_inline
def _view_lengths(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    parents: IntArray,
    children: IntArray,
    tracked: int,
) -> FloatArray:
    """(N, B) each view's bone lengths, metres (``((dx² + dy²) + dz²)`` then the square root);
    NaN where an end is not ``tracked`` or the length is not finite."""
    views, bones = joints.shape[0], parents.shape[0]
    lengths = np.empty((views, bones))
    for i in range(views):
        for b in range(bones):
            parent, child = parents[b], children[b]
            length = np.nan
            if states[i, parent] == tracked and states[i, child] == tracked:
                dx = joints[i, child, 0] - joints[i, parent, 0]
                dy = joints[i, child, 1] - joints[i, parent, 1]
                dz = joints[i, child, 2] - joints[i, parent, 2]
                length = np.sqrt((dx * dx + dy * dy) + dz * dz)
                if not np.isfinite(length):
                    length = np.nan
            lengths[i, b] = length
    return lengths


# --- The sample window: what a bone model estimates from -----------------------------------------


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
    _window_medians_loop(plain(rows), out)
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
def _window_medians_loop(rows: FloatArray, out: FloatArray) -> None:
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
