"""The agreement terms of the mirror cost: mean distances between the lateral joints of two
views, or of a view and the person's last fused skeleton, under both labellings.

:func:`lateral_loop` fills every pair's (2, 2) and every view's (2,) table at once for the
mirror scoring (:mod:`skelfuse.fusion.mirror_scores`), in a loop compiled with numba. Its sums
are numpy's over a last axis (:func:`pairwise`), so a mean is what ``d.sum(-1) / count`` gives.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.jit import jit
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

LATERAL_JOINTS: Final = np.array([j for j in range(JOINT_COUNT) if MIRROR_PERMUTATION[j] != j])
"""The 20 joints that have a left or right side."""
LATERAL_SWAP: Final = np.array(
    [LATERAL_JOINTS.tolist().index(MIRROR_PERMUTATION[j]) for j in LATERAL_JOINTS]
)
"""Where each lateral joint's other side is in :data:`LATERAL_JOINTS`."""


@jit
def pairwise(values: FloatArray, n: int) -> float:
    """numpy's sum of the first ``n`` (≤ 128) ``values`` along a contiguous last axis: one by one
    below 8, else eight running sums, added as a tree, then the rest one by one; from 0."""
    total: float = 0.0
    if n < 8:
        for i in range(n):
            total += values[i]
        return 0.0 + total
    r0, r1, r2, r3 = values[0], values[1], values[2], values[3]
    r4, r5, r6, r7 = values[4], values[5], values[6], values[7]
    i = 8
    while i < n - (n % 8):
        r0 += values[i]
        r1 += values[i + 1]
        r2 += values[i + 2]
        r3 += values[i + 3]
        r4 += values[i + 4]
        r5 += values[i + 5]
        r6 += values[i + 6]
        r7 += values[i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += values[i]
        i += 1
    return 0.0 + total


@jit
def _distance(points: FloatArray, i: int, a: int, others: FloatArray, j: int, b: int) -> float:
    """``sqrt((dx² + dy²) + dz²)`` between ``points[i, a]`` and ``others[j, b]`` (3,), the
    order ``np.linalg.norm`` sums three squares in (scalar reads: no array views in loops)."""
    dx = points[i, a, 0] - others[j, b, 0]
    dy = points[i, a, 1] - others[j, b, 1]
    dz = points[i, a, 2] - others[j, b, 2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@jit
def _mean_of_finite(d: FloatArray, scratch: FloatArray) -> float:
    """The mean of the finite distances ``d`` (L,), 0 where none is (``scratch`` (L,): 0 where
    not finite)."""
    count = 0
    for m in range(len(d)):
        if math.isfinite(d[m]):
            scratch[m] = d[m]
            count += 1
        else:
            scratch[m] = 0.0
    if count == 0:
        return 0.0
    return pairwise(scratch, len(d)) / count


@jit
def lateral_loop(
    views: FloatArray,
    lateral: IntArray,
    swap: IntArray,
    first: IntArray,
    second: IntArray,
    references: FloatArray,
    has_reference: BoolArray,
    pair: FloatArray,
    to_ref: FloatArray,
) -> None:
    """Fill ``pair`` (K, 2, 2) with each pair's mean lateral distance under labellings
    (c_first, c_second) and ``to_ref`` (N, 2) with each labelling's to the reference.

    views: (N, 25, 3) metres; lateral: (L,) the lateral joints; swap: (L,) where each one's
    other side is among them; first, second: (K,) each pair's views; references: (N, 25, 3)
    each view's person's skeleton, read where ``has_reference`` (N,); ``to_ref`` is 0
    elsewhere. A mean is over the joints finite in both (0 where none is). The swapped
    labelling only reorders a view's lateral joints (an involution), so of a pair's four
    label combinations two are measured and the other two read through the swap.
    """
    size = len(lateral)
    d0 = np.empty(size)
    d1 = np.empty(size)
    row = np.empty(size)
    scratch = np.empty(size)
    for k in range(len(first)):
        i, j = first[k], second[k]
        for m in range(size):  # i as reported against j as reported (0, 0), swapped (0, 1)
            d0[m] = _distance(views, i, lateral[m], views, j, lateral[m])
            d1[m] = _distance(views, i, lateral[m], views, j, lateral[swap[m]])
        pair[k, 0, 0] = _mean_of_finite(d0, scratch)
        pair[k, 0, 1] = _mean_of_finite(d1, scratch)
        for m in range(size):  # (1, 0) is (0, 1) read through the swap, (1, 1) is (0, 0)
            row[m] = d1[swap[m]]
        pair[k, 1, 0] = _mean_of_finite(row, scratch)
        for m in range(size):
            row[m] = d0[swap[m]]
        pair[k, 1, 1] = _mean_of_finite(row, scratch)
    for v in range(views.shape[0]):
        if not has_reference[v]:
            to_ref[v, 0] = to_ref[v, 1] = 0.0
            continue
        for m in range(size):
            d0[m] = _distance(views, v, lateral[m], references, v, lateral[m])
            d1[m] = _distance(views, v, lateral[swap[m]], references, v, lateral[m])
        to_ref[v, 0] = _mean_of_finite(d0, scratch)
        to_ref[v, 1] = _mean_of_finite(d1, scratch)
