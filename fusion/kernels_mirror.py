"""The mirror step's scoring as loops, for a compiled kernel.

:func:`lateral_loop` is :func:`skelfuse.fusion.mirror_distances.lateral_terms` and
:func:`score_loop` the scoring of :func:`skelfuse.fusion.mirror.choose_labellings_and_forward`
for persons whose facing is known, written as scalar code: :mod:`skelfuse.fusion.kernels`
compiles them with numba. The same IEEE operations in the same order as numpy's, so the same
bits and the same choices: a sum over an array's last axis is numpy's pairwise sum
(:func:`pairwise`), a sum over another axis adds element after element from 0.

Imported only by :mod:`skelfuse.fusion.kernels` when the kernels run; without numba
:func:`~skelfuse.fusion.kernels_jit.jit` leaves the functions plain Python (slow, same results).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import jit

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]
Terms = tuple[float, float, float, float, float, float]
"""The track, geometry and anatomy weights, the swap prior, the hysteresis, and 1.0 when the
last decisions count (0.0: none known)."""


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
    """``sqrt((dx² + dy²) + dz²)`` between ``points[i, a]`` and ``others[j, b]`` (3,), as
    ``_joint_distances`` (scalar reads: no array views in the loops)."""
    dx = points[i, a, 0] - others[j, b, 0]
    dy = points[i, a, 1] - others[j, b, 1]
    dz = points[i, a, 2] - others[j, b, 2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@jit
def _mean_of_finite(d: FloatArray, scratch: FloatArray) -> float:
    """``_mean_of_finite`` of one row of distances (0 in ``scratch`` where not finite)."""
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
    """Fill ``pair`` (K, 2, 2) and ``to_ref`` (N, 2) as ``lateral_terms`` does.

    views: (N, 25, 3); lateral: (L,) the lateral joints; swap: (L,) where each one's other side
    is among them; first, second: (K,) each pair's views; references: (N, 25, 3) each view's
    person's skeleton, read where ``has_reference`` (N,); ``to_ref`` is 0 elsewhere.
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


@jit
def _maximum(a: float, b: float) -> float:
    """``np.maximum(a, b)``: NaN passes through, a tie keeps ``a``."""
    if a >= b or a != a:
        return a
    return b


@jit
def _unary(
    tables: FloatArray,
    terms: Terms,
    lo: int,
    n: int,
    combo: int,
    scratch: FloatArray,
    sums: FloatArray,
) -> None:
    """``sums[t]`` = Σ over the person's views of ``tables[view, t, c_view]`` (pairwise)."""
    for t in range(3):
        if t == 2 and terms[2] == 0.0:  # no anatomy term
            sums[t] = 0.0
            continue
        for i in range(n):
            scratch[i] = tables[lo + i, t, (combo >> i) & 1]
        sums[t] = pairwise(scratch, n)


@jit
def _exact(
    pair: FloatArray,
    tables: FloatArray,
    previous: IntArray,
    terms: Terms,
    lo: int,
    n: int,
    first_pair: int,
    combo: int,
    scratch: FloatArray,
    sums: FloatArray,
) -> float:
    """Labelling ``combo``'s cost for one person, term by term in numpy's order."""
    cost: float = 0.0
    k = first_pair
    for i in range(n):
        for j in range(i + 1, n):
            cost += pair[k, (combo >> i) & 1, (combo >> j) & 1]
            k += 1
    _unary(tables, terms, lo, n, combo, scratch, sums)
    cost += terms[0] * sums[0]
    cost += terms[1] * sums[1]
    if terms[2] != 0.0:
        cost += terms[2] * sums[2]
    swaps = 0
    changed = 0
    for i in range(n):
        bit = (combo >> i) & 1
        swaps += bit
        if previous[lo + i] >= 0 and bit != previous[lo + i]:
            changed += 1
    cost += terms[3] * swaps
    if terms[5] != 0.0:
        cost += terms[4] * changed
    return cost


@jit
def _view_cost(tables: FloatArray, previous: IntArray, terms: Terms, v: int, b: int) -> float:
    """A view's own share of a labelling's cost with label ``b`` (the screen's estimate)."""
    cost: float = terms[0] * tables[v, 0, b] + terms[1] * tables[v, 1, b] + terms[3] * b
    if terms[2] != 0.0:
        cost += terms[2] * tables[v, 2, b]
    if terms[5] != 0.0 and previous[v] >= 0 and b != previous[v]:
        cost += terms[4]
    return cost


@jit
def _screen(
    pair: FloatArray,
    tables: FloatArray,
    previous: IntArray,
    terms: Terms,
    lo: int,
    n: int,
    first_pair: int,
    margin: float,
    estimate: FloatArray,
) -> int:
    """The labelling when a quick estimate of every cost settles it, else −1 (as ``screen``).

    The estimates are added up in Gray-code order (one view changes label from one labelling
    to the next), so they differ from the exact costs by rounding only (far below ``margin``).
    ``field[v]``: how much swapping view v adds through its pairs, given the others' labels;
    ``coupling[w, v]``: how much ``field[w]`` changes when view v is swapped.
    """
    own = np.empty((n, 2))
    field = np.zeros(n)
    coupling = np.zeros((n, n))
    cost = 0.0
    k = first_pair
    for i in range(n):
        own[i, 0] = _view_cost(tables, previous, terms, lo + i, 0)
        own[i, 1] = _view_cost(tables, previous, terms, lo + i, 1)
        cost += own[i, 0]
        for j in range(i + 1, n):
            d00, d01, d10, d11 = pair[k, 0, 0], pair[k, 0, 1], pair[k, 1, 0], pair[k, 1, 1]
            cost += d00
            field[i] += d10 - d00  # i swapped, j as reported
            field[j] += d01 - d00
            coupling[i, j] = (d11 - d01) - (d10 - d00)
            coupling[j, i] = coupling[i, j]
            k += 1
    labels = np.zeros(n, dtype=np.intp)
    estimate[0] = cost
    combo = 0
    for g in range(1, 2**n):
        v = 0
        while not (g >> v) & 1:  # the label that changes from labelling g − 1 to g
            v += 1
        step = 1.0 - 2.0 * labels[v]  # +1: swapped now, −1: back as reported
        cost += own[v, labels[v] ^ 1] - own[v, labels[v]] + step * field[v]
        for w in range(n):
            field[w] += step * coupling[w, v]
        labels[v] ^= 1
        combo ^= 1 << v
        estimate[combo] = cost
    best = 0
    for c in range(2**n):
        if not math.isfinite(estimate[c]):
            return -1
        if estimate[c] < estimate[best]:
            best = c
    for c in range(2**n):
        if c != best and not estimate[c] > estimate[best] + margin:
            return -1
    return best


@jit
def score_loop(
    views: FloatArray,
    sensor_positions: FloatArray,
    starts: IntArray,
    facings: FloatArray,
    pair: FloatArray,
    to_ref: FloatArray,
    anatomy_factors: FloatArray,
    previous: IntArray,
    terms: Terms,
    screen_from: int,
    margin: float,
    mirrored: BoolArray,
) -> None:
    """Fill ``mirrored`` (N,) with each person's cheapest labelling (``choose_labellings``).

    views: (N, 25, 3); sensor_positions: (N, 3); starts: (P + 1,) each person's first view;
    facings: (P, 3) each person's known facing; pair: (K, 2, 2) and to_ref: (N, 2) from
    :func:`lateral_loop`; anatomy_factors: (N, 2, 25) range-of-motion factors (read when
    ``terms[2]``); previous: (N,) last decisions (−1 unknown); terms: track weight, geometry
    weight, anatomy weight, swap prior, hysteresis, whether ``previous`` counts.
    """
    total = views.shape[0]
    tables = np.zeros((total, 3, 2))
    column = np.empty(anatomy_factors.shape[2])
    scratch = np.empty(max(total, 1))
    sums = np.empty(3)
    first_pair = 0
    for p in range(len(starts) - 1):
        lo, hi = starts[p], starts[p + 1]
        n = hi - lo
        # Where the person stands: the mean SpineBase of its views, component by component.
        body = np.zeros(3)
        for c in range(3):
            found = 0.0
            total_c = 0.0
            for v in range(lo, hi):
                x = views[v, 0, c]
                if math.isfinite(x):
                    total_c += x
                    found += 1.0
            body[c] = total_c / found  # 0 / 0: NaN, as numpy
        for v in range(lo, hi):
            t0 = (sensor_positions[v, 0] - body[0]) * 1.0
            t1 = (sensor_positions[v, 1] - body[1]) * 0.0
            t2 = (sensor_positions[v, 2] - body[2]) * 1.0
            norm = math.sqrt(0.0 + t0 * t0 + t1 * t1 + t2 * t2)
            t0, t1, t2 = t0 / norm, t1 / norm, t2 / norm
            cos = facings[p, 0] * t0 + facings[p, 1] * t1 + facings[p, 2] * t2
            if cos != cos:
                cos = 0.0
            tables[v, 0, 0], tables[v, 0, 1] = to_ref[v, 0], to_ref[v, 1]
            tables[v, 1, 0] = _maximum(-cos, 0.0)
            tables[v, 1, 1] = _maximum(cos, 0.0)
            if terms[2] != 0.0:
                for b in range(2):
                    for m in range(len(column)):
                        column[m] = 1.0 - anatomy_factors[v, b, m]
                    tables[v, 2, b] = pairwise(column, len(column))
        best = -1
        if n >= screen_from:
            estimate = np.empty(2**n)
            best = _screen(pair, tables, previous, terms, lo, n, first_pair, margin, estimate)
        if best < 0:
            best = 0
            lowest = _exact(pair, tables, previous, terms, lo, n, first_pair, 0, scratch, sums)
            for c in range(1, 2**n):
                if lowest != lowest:  # np.argmin stops at the first NaN
                    break
                cost = _exact(pair, tables, previous, terms, lo, n, first_pair, c, scratch, sums)
                if cost < lowest or cost != cost:
                    best, lowest = c, cost
        for i in range(n):
            mirrored[lo + i] = (best >> i) & 1 == 1
        first_pair += n * (n - 1) // 2
