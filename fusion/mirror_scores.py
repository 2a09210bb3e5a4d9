"""The mirror scoring as loops compiled with numba: every labelling of every person's views
costed, the cheapest chosen, and each view's anatomical evidence against its labelling.

:func:`scored_loop` runs the whole stage in one call (the per-call cost of many small steps
outweighed their work): the range-of-motion factors and forward axes of both labellings
(:func:`~skelfuse.fusion.anatomy.rom_loop`), the agreement terms
(:func:`lateral_loop`), the costs (:func:`score_loop`) and
the evidence (:func:`evidence_loop`). Costs are summed term by term as
:mod:`skelfuse.fusion.mirror` describes, each sum over a person's views or a view's joints as
numpy's over a last axis (:func:`pairwise`); ties go to the
first labelling in index order. From ``screen_from`` views on, persons whose facing is known
are screened first (:func:`_screen`).

The agreement terms of the cost (second section) are mean distances between the lateral joints
of two views, or of a view and the person's last fused skeleton, under both labellings:
:func:`lateral_loop` fills every pair's (2, 2) and every view's (2,) table at once. Its sums are
numpy's over a last axis (:func:`pairwise`), so a mean is what ``d.sum(-1) / count`` gives.

Where each person's views and view pairs are among a frame's views (last section), as index
arrays built once per shape (:func:`slots`, :func:`layout`), and the constants of the
labellings' screen. A labelling gives each of a person's n views a label, as reported (0) or
swapped (1); there are C = 2^n. :mod:`skelfuse.fusion.mirror` scores them all; from
:data:`SCREEN_FROM_VIEWS` views on, persons whose facing is known are screened with a quick
estimate first.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import rom_loop
from skelfuse.jit import jit
from skelfuse.protocol.skeleton import JOINT_COUNT, MIRROR_PERMUTATION

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]
Terms = tuple[float, float, float, float, float, float]
"""The track, geometry and anatomy weights, the swap prior, the hysteresis, and 1.0 when the
last decisions count (0.0: none known)."""

_LARGEST = float(np.finfo(np.float64).max)
"""What ``np.nan_to_num`` puts in place of +inf."""


@jit
def _finite(x: float) -> float:
    """``np.nan_to_num`` of one value: NaN 0, ±inf the largest float of that sign."""
    if x != x:
        return 0.0
    if x == math.inf:
        return _LARGEST
    if x == -math.inf:
        return -_LARGEST
    return x


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
def _candidate(
    forward: FloatArray, to_sensor: FloatArray, lo: int, n: int, combo: int, scratch: FloatArray
) -> float:
    """The geometry term of labelling ``combo`` for a person whose facing is unknown: the facing
    is the unit sum of its labelled views' horizontal forward axes (``forward`` (N, 2, 3)),
    against each view's horizontal unit direction to its sensor (``to_sensor`` (N, 3))."""
    f0 = f1 = f2 = 0.0
    for i in range(n):
        axis = forward[lo + i, (combo >> i) & 1]
        f0 += _finite(axis[0] * 1.0)
        f1 += _finite(axis[1] * 0.0)
        f2 += _finite(axis[2] * 1.0)
    norm = math.sqrt((f0 * f0 + f1 * f1) + f2 * f2)
    if norm > 0.0:
        f0, f1, f2 = f0 / norm, f1 / norm, f2 / norm
    else:  # no axis known: NaN (written out, so that it holds as plain Python too)
        f0 = f1 = f2 = math.nan
    for i in range(n):
        t = to_sensor[lo + i]
        cos = _finite((f0 * t[0] + f1 * t[1]) + f2 * t[2])
        scratch[i] = _maximum(cos, 0.0) if (combo >> i) & 1 else _maximum(-cos, 0.0)
    return pairwise(scratch, n)


@jit
def _exact(
    pair: FloatArray,
    tables: FloatArray,
    previous: IntArray,
    terms: Terms,
    places: tuple[int, int, int, int],
    geometry: tuple[bool, bool, FloatArray, FloatArray],
    scratch: FloatArray,
    sums: FloatArray,
) -> float:
    """Labelling ``combo``'s cost for one person, term by term: places (lo, n, first pair,
    combo); geometry (with a reference, facing known, forward axes, directions to sensors)."""
    lo, n, first_pair, combo = places
    with_ref, known, forward, to_sensor = geometry
    cost: float = 0.0
    k = first_pair
    for i in range(n):
        for j in range(i + 1, n):
            cost += pair[k, (combo >> i) & 1, (combo >> j) & 1]
            k += 1
    _unary(tables, terms, lo, n, combo, scratch, sums)
    if with_ref:
        cost += terms[0] * sums[0]
    if known:
        cost += terms[1] * sums[1]
    else:
        cost += terms[1] * _candidate(forward, to_sensor, lo, n, combo, scratch)
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
def _person_tables(
    views: FloatArray,
    sensor_positions: FloatArray,
    facing: FloatArray,
    span: tuple[int, int, bool],
    terms: tuple[FloatArray, FloatArray, float],
    out: tuple[FloatArray, FloatArray, FloatArray],
) -> None:
    """Fill one person's rows of ``tables`` (N, 3, 2) (track, geometry with a known facing,
    anatomy per label) and ``to_sensor`` (N, 3): the horizontal unit direction from where the
    person stands (its views' mean SpineBase) to each view's sensor. span: (lo, hi, facing
    known); terms: to_ref (N, 2), the factors (N, 2, 25), the anatomy weight."""
    lo, hi, known = span
    to_ref, factors, anatomy = terms
    tables, to_sensor, column = out
    body = np.zeros(3)
    for c in range(3):
        found = 0.0
        total = 0.0
        for v in range(lo, hi):
            x = views[v, 0, c]
            if math.isfinite(x):
                total += x
                found += 1.0
        body[c] = total / found  # 0 / 0: NaN, as numpy
    for v in range(lo, hi):
        t0 = (sensor_positions[v, 0] - body[0]) * 1.0
        t1 = (sensor_positions[v, 1] - body[1]) * 0.0
        t2 = (sensor_positions[v, 2] - body[2]) * 1.0
        norm = math.sqrt(0.0 + t0 * t0 + t1 * t1 + t2 * t2)
        t0, t1, t2 = t0 / norm, t1 / norm, t2 / norm
        to_sensor[v, 0], to_sensor[v, 1], to_sensor[v, 2] = t0, t1, t2
        tables[v, 0, 0], tables[v, 0, 1] = to_ref[v, 0], to_ref[v, 1]
        if known:
            cos = facing[0] * t0 + facing[1] * t1 + facing[2] * t2
            if cos != cos:
                cos = 0.0
            tables[v, 1, 0] = _maximum(-cos, 0.0)
            tables[v, 1, 1] = _maximum(cos, 0.0)
        if anatomy != 0.0:
            for b in range(2):
                for m in range(len(column)):
                    column[m] = 1.0 - factors[v, b, m]
                tables[v, 2, b] = pairwise(column, len(column))


@jit
def score_loop(
    views: FloatArray,
    sensor_positions: FloatArray,
    people: tuple[IntArray, BoolArray, FloatArray],
    measured: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    previous: IntArray,
    terms: Terms,
    screen: tuple[int, float],
    mirrored: BoolArray,
) -> None:
    """Fill ``mirrored`` (N,) with each person's cheapest labelling.

    views: (N, 25, 3); sensor_positions: (N, 3); people: (P + 1,) each person's first view
    then N, (P, 2) whether it has a reference and a known facing, (P, 3) the facings;
    measured: pair (K, 2, 2) and to_ref (N, 2) from
    :func:`lateral_loop`, the range-of-motion factors
    (N, 2, 25) and forward axes (N, 2, 3) of both labellings; previous: (N,) last decisions
    (−1 unknown); terms: see :data:`Terms`; screen: the view count from which persons with a
    known facing are screened, and the margin.
    """
    starts, kinds, facings = people
    pair, to_ref, factors, forward = measured
    total = views.shape[0]
    tables = np.zeros((total, 3, 2))
    to_sensor = np.empty((total, 3))
    column = np.empty(factors.shape[2])
    scratch = np.empty(max(total, 1))
    sums = np.empty(3)
    first_pair = 0
    for p in range(len(starts) - 1):
        lo, hi = starts[p], starts[p + 1]
        n = hi - lo
        with_ref, known = kinds[p, 0], kinds[p, 1]
        _person_tables(views, sensor_positions, facings[p], (lo, hi, known),
                       (to_ref, factors, terms[2]), (tables, to_sensor, column))  # fmt: skip
        geometry = (with_ref, known, forward, to_sensor)
        best = -1
        if known and n >= screen[0]:
            estimate = np.empty(2**n)
            best = _screen(pair, tables, previous, terms, lo, n, first_pair, screen[1], estimate)
        if best < 0:
            best = 0
            lowest = _exact(pair, tables, previous, terms, (lo, n, first_pair, 0), geometry,
                            scratch, sums)  # fmt: skip
            for c in range(1, 2**n):
                if lowest != lowest:  # np.argmin stops at the first NaN
                    break
                cost = _exact(pair, tables, previous, terms, (lo, n, first_pair, c), geometry,
                              scratch, sums)  # fmt: skip
                if cost < lowest or cost != cost:
                    best, lowest = c, cost
        for i in range(n):
            mirrored[lo + i] = (best >> i) & 1 == 1
        first_pair += n * (n - 1) // 2


@jit
def evidence_loop(
    factors: FloatArray,
    mirrored: BoolArray,
    person_of: IntArray,
    per_view: FloatArray,
    evidence: FloatArray,
) -> None:
    """Fill ``per_view`` (N,) with each view's anatomical evidence against its labelling, in
    joints: Σ (1 − factor) as labelled − as swapped (0 where not finite, ±inf the largest
    float), and ``evidence`` (P,) with its sum per person, view after view from 0.

    factors: (N, 2, 25) range-of-motion factors as reported and swapped; mirrored: (N,) the
    labelling chosen; person_of: (N,) each view's person.
    """
    column = np.empty(factors.shape[2])
    out_of_range = np.empty(2)
    for p in range(len(evidence)):
        evidence[p] = 0.0
    for v in range(factors.shape[0]):
        for b in range(2):
            for m in range(len(column)):
                column[m] = 1.0 - factors[v, b, m]
            out_of_range[b] = pairwise(column, len(column))
        chosen = 1 if mirrored[v] else 0
        value = out_of_range[chosen] - out_of_range[1 - chosen]
        value = _finite(value)
        per_view[v] = value
        evidence[person_of[v]] += value


@jit
def scored_loop(
    views: FloatArray,
    sensor_positions: FloatArray,
    places: tuple[IntArray, IntArray, IntArray, IntArray],
    known: tuple[BoolArray, FloatArray, FloatArray, IntArray],
    terms: Terms,
    tables: tuple[IntArray, IntArray, IntArray],
    settings: tuple[int, float, float, FloatArray, FloatArray],
    out: tuple[BoolArray, FloatArray, FloatArray, FloatArray, FloatArray],
) -> None:
    """The whole mirror scoring of N views of P persons (see the module docstring).

    places: (P + 1,) each person's first view then N, (N,) each view's person, (K,) each
    pair's first and second view; known: (P, 2) whether each person has a reference and a
    known facing, (P, 3) the facings, (P, 25, 3) the references (read where there is one),
    (N,) each view's last decision (−1 unknown); tables: the lateral joints, where each one's
    other side is among them, the left/right permutation (25,); settings: the screen's view
    count and margin, the range-of-motion scale (degrees) and the angle limits low, high (13,);
    out: mirrored (N,), factors (N, 2, 25) (all ones on entry), forward (N, 2, 3), per_view
    (N,) and evidence (P,).
    """
    mirrored, factors, forward, per_view, evidence = out
    starts, person_of, first, second = places
    kinds, facings, references, previous = known
    lateral, swap, permutation = tables
    total, size = views.shape[0], views.shape[1]
    both = np.empty((total, 2, size, 3))  # both labellings, as rows of (2N, 25, 3)
    own = np.empty((total, size, 3))  # each view's person's reference
    has_reference = np.empty(total, dtype=np.bool_)
    for v in range(total):
        has_reference[v] = kinds[person_of[v], 0]
        for j in range(size):
            for c in range(3):
                both[v, 0, j, c] = views[v, j, c]
                both[v, 1, j, c] = views[v, permutation[j], c]
                own[v, j, c] = references[person_of[v], j, c]
    rom = (settings[2], settings[3], settings[4])
    rom_loop(both.reshape(2 * total, size, 3), rom, factors.reshape(2 * total, size),
             forward.reshape(2 * total, 3), np.empty((2 * total, 13)))  # fmt: skip
    pair = np.empty((len(first), 2, 2))
    to_ref = np.empty((total, 2))
    lateral_loop(views, lateral, swap, first, second, own, has_reference, pair, to_ref)
    score_loop(views, sensor_positions, (starts, kinds, facings), (pair, to_ref, factors, forward),
               previous, terms, (settings[0], settings[1]), mirrored)  # fmt: skip
    evidence_loop(factors, mirrored, person_of, per_view, evidence)


# --- The agreement terms: lateral-joint distances under both labellings --------------------------


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


# --- Where a frame's views are: index arrays built once per shape; the screen's constants --------


MAX_VIEWS: Final = 10


PAIRS: Final = tuple(
    (
        np.array([i for i in range(n) for j in range(i + 1, n)], dtype=np.intp),
        np.array([j for i in range(n) for j in range(i + 1, n)], dtype=np.intp),
    )
    for n in range(MAX_VIEWS + 1)
)
"""Per view count n: the view pairs i < j in the order they are summed."""


SCREEN_FROM_VIEWS: Final = 6
"""From this many views on, labellings are screened with a quick estimate before exact scoring."""


SCREEN_MARGIN_M: Final = 1e-9
"""Labellings whose estimate is within this of the best are scored exactly. The estimate differs
from the exact cost by rounding only (≈ 1e-14 m), far below it, so the exact minimum is always
among them and the choice is the one the full enumeration makes."""


def _frozen(array: npt.ArrayLike) -> IntArray:
    """An index array that stays as built: layouts are shared between calls."""
    result: IntArray = np.array(array, dtype=np.intp)
    result.flags.writeable = False
    return result


@dataclass(frozen=True, slots=True)
class Slots:
    """Where each person's views are: starts (P + 1,) first view of each person, then N;
    person_of, slot_of (N,) each view's person and place among its views; widest: the most
    views of one person."""

    starts: IntArray
    person_of: IntArray
    slot_of: IntArray
    widest: int


@functools.lru_cache(maxsize=256)
def slots(counts: tuple[int, ...]) -> Slots:
    """The :class:`Slots` of persons with ``counts`` views each (cached: frames repeat)."""
    starts = np.cumsum([0, *counts])
    person_of = np.repeat(np.arange(len(counts)), counts)
    slot_of = np.arange(int(starts[-1])) - starts[person_of]
    return Slots(_frozen(starts), _frozen(person_of), _frozen(slot_of), max(counts, default=0))


@dataclass(frozen=True, slots=True)
class Layout:
    """Index arrays for one frame's persons (:func:`layout`): starts (P + 1,) first view of each
    person, then N; person_of (N,) each view's person; first, second (K,) the views of each
    pair i < j, person by person in :data:`PAIRS` order."""

    starts: IntArray
    person_of: IntArray
    first: IntArray
    second: IntArray


@functools.lru_cache(maxsize=256)
def layout(counts: tuple[int, ...]) -> Layout:
    """The :class:`Layout` of persons with ``counts`` views each (1 … :data:`MAX_VIEWS`).
    Frames repeat the same shapes, so the layouts are cached."""
    places = slots(counts)
    starts = places.starts
    firsts: list[IntArray] = [np.zeros(0, dtype=np.intp)]
    seconds: list[IntArray] = [np.zeros(0, dtype=np.intp)]
    for p, n in enumerate(counts):
        firsts.append(PAIRS[n][0] + starts[p])
        seconds.append(PAIRS[n][1] + starts[p])
    return Layout(
        starts,
        places.person_of,
        _frozen(np.concatenate(firsts)),
        _frozen(np.concatenate(seconds)),
    )
