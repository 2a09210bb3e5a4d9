"""Every labelling of n views of one person, as index tables built once, and the quick screen.

A labelling gives each of a person's n views a label, as reported (0) or swapped (1); there are
C = 2^n. :mod:`skelfuse.fusion.mirror` scores them all; from :data:`SCREEN_FROM_VIEWS` views on,
:func:`screen` settles most persons with one matrix product first.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
MAX_VIEWS: Final = 10


# Per view count n (0 … MAX_VIEWS), built once: every labelling (C = 2^n, n), its transpose,
# its number of swapped views, the view pairs i < j in the order they are summed, and 0 … n−1.
COMBOS: Final = tuple(
    ((np.arange(2**n)[:, None] >> np.arange(n)[None, :]) & 1).astype(np.intp)
    for n in range(MAX_VIEWS + 1)
)


PAIRS: Final = tuple(
    (
        np.array([i for i in range(n) for j in range(i + 1, n)], dtype=np.intp),
        np.array([j for i in range(n) for j in range(i + 1, n)], dtype=np.intp),
    )
    for n in range(MAX_VIEWS + 1)
)


ROWS: Final = tuple(np.arange(n)[None, :] for n in range(MAX_VIEWS + 1))


PAIR_ROWS: Final = tuple(np.arange(n * (n - 1) // 2)[:, None] for n in range(MAX_VIEWS + 1))


# Flat indices into a (pairs, 2, 2) block and an (n, 2) per-view table: entry [pair, c] is
# D[pair, c_i, c_j] and [c, i] is T[i, c_i] for labelling c (one take instead of a fancy index).
PAIR_TAKE: Final = tuple(
    4 * PAIR_ROWS[n] + 2 * COMBOS[n].T[PAIRS[n][0]] + COMBOS[n].T[PAIRS[n][1]]
    for n in range(MAX_VIEWS + 1)
)


VIEW_TAKE: Final = tuple(2 * ROWS[n] + COMBOS[n] for n in range(MAX_VIEWS + 1))


SWAPS: Final = tuple(c.sum(axis=1) for c in COMBOS)


SCREEN_FROM_VIEWS: Final = 6
"""From this many views on, labellings are screened with a quick estimate before exact scoring."""


SCREEN_MARGIN_M: Final = 1e-9
"""Labellings whose estimate is within this of the best are scored exactly. The estimate differs
from the exact cost by rounding only (≈ 1e-14 m), far below it, so the exact minimum is always
among them and the choice is the one the full enumeration makes."""


@dataclass(frozen=True, slots=True)
class Group:
    """Persons scored together: the same view count ``n`` and the same kinds of terms.

    people: (G,) person indices; views_of: (G, n) their views' rows; pair_rows: (G·k,) their
    view pairs' rows (k = n(n − 1)/2 per person, :data:`PAIRS` order).
    """

    n: int
    with_ref: bool
    known_facing: bool
    people: IntArray
    views_of: IntArray
    pair_rows: IntArray


@dataclass(frozen=True, slots=True)
class Layout:
    """Index arrays for one frame's persons, built once per shape (:func:`layout`).

    starts: (P + 1,) first view of each person, then N; person_of, slot_of: (N,) each view's
    person and its place among the person's views; widest: the most views of one person;
    first, second: (K,) the views of each pair i < j, person by person; groups: the persons
    scored together, in the order their first member comes.
    """

    starts: IntArray
    person_of: IntArray
    slot_of: IntArray
    widest: int
    first: IntArray
    second: IntArray
    groups: tuple[Group, ...]


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


@functools.lru_cache(maxsize=256)
def layout(counts: tuple[int, ...], kinds: tuple[tuple[bool, bool], ...]) -> Layout:
    """The :class:`Layout` of persons with ``counts`` views each (1 … :data:`MAX_VIEWS`).

    ``kinds``: per person, (has a reference skeleton, has a known facing). Frames repeat the
    same shapes, so the layouts are cached: building them is Python work per person and pair.
    """
    places = slots(counts)
    starts = places.starts
    firsts: list[IntArray] = [np.zeros(0, dtype=np.intp)]
    seconds: list[IntArray] = [np.zeros(0, dtype=np.intp)]
    pair_start = [0]
    for p, n in enumerate(counts):
        firsts.append(PAIRS[n][0] + starts[p])
        seconds.append(PAIRS[n][1] + starts[p])
        pair_start.append(pair_start[-1] + n * (n - 1) // 2)
    members: dict[tuple[int, bool, bool], list[int]] = {}
    for p, (n, (with_ref, known_facing)) in enumerate(zip(counts, kinds, strict=True)):
        members.setdefault((n, with_ref, known_facing), []).append(p)
    groups = []
    for (n, with_ref, known_facing), people in members.items():
        chosen = np.array(people, dtype=np.intp)
        k = n * (n - 1) // 2
        pairs_of = np.array(pair_start)[chosen][:, None] + np.arange(k)[None, :]
        groups.append(
            Group(
                n,
                with_ref,
                known_facing,
                _frozen(chosen),
                _frozen(starts[chosen][:, None] + np.arange(n)[None, :]),
                _frozen(pairs_of.ravel()),
            )
        )
    return Layout(
        starts,
        places.person_of,
        places.slot_of,
        places.widest,
        _frozen(np.concatenate(firsts)),
        _frozen(np.concatenate(seconds)),
        tuple(groups),
    )


def per_view_sum(table: FloatArray, views_of: IntArray, take: IntArray) -> FloatArray:
    """(G, C) Σ over a person's views of ``table[view, c_view]``, for G persons of n views.

    ``views_of``: (G·n,) each person's views in order; ``take``: :data:`VIEW_TAKE` of n.
    """
    size = len(views_of) // take.shape[1]
    summed: FloatArray = table[views_of].reshape(size, -1)[:, take].sum(axis=2)
    return summed


@functools.cache
def design(n: int) -> FloatArray:
    """(C, 4·pairs + 2·n) one-hot design: labelling c's pair states, then its view labels."""
    count = 2**n
    pairs = n * (n - 1) // 2
    design = np.zeros((count, 4 * pairs + 2 * n))
    rows = np.arange(count)[:, None]
    design[rows, PAIR_TAKE[n].T] = 1.0
    design[rows, 4 * pairs + VIEW_TAKE[n]] = 1.0
    return design


@dataclass(frozen=True, slots=True)
class Halves:
    """The labellings of n views split into the first ``low`` views and the other ``high``.

    Labelling c = a + 2^low · b, a labelling ``a`` of the first views and ``b`` of the others.
    Its cost is within(a) + within(b) + across(a, b): the pairs inside each half and each
    half's views in ``design(low)`` / ``design(high)`` form, and the pairs across as
    ``one_low @ across @ one_high.T``, with ``across`` gathered from the person's pair table.

    low_columns, high_columns: columns of [block | unary] in the order of ``design(low)``,
    ``design(high)``; across: (2·low, 2·high) columns, entry [2i + s, 2j + t] that of
    D[pair(i, low + j), s, t]; one_low, one_high: (2^m, 2·m) each labelling's view labels
    one-hot.
    """

    low: int
    high: int
    low_columns: IntArray
    high_columns: IntArray
    across: IntArray
    one_low: FloatArray
    one_high: FloatArray


@functools.cache
def halves(n: int) -> Halves:
    """The :class:`Halves` of n ≥ 2 views (built once per n)."""
    low, high = n // 2, n - n // 2
    first, second = PAIRS[n]
    pair_of = {(int(i), int(j)): p for p, (i, j) in enumerate(zip(first, second, strict=True))}
    unary_from = 4 * len(first)  # the unary columns follow the pairs' 4 each

    def columns(offset: int, m: int) -> IntArray:
        within = [
            4 * pair_of[(int(i) + offset, int(j) + offset)] + q
            for i, j in zip(*PAIRS[m], strict=True)
            for q in range(4)
        ]
        views = [unary_from + 2 * (offset + i) + s for i in range(m) for s in range(2)]
        return np.array(within + views, dtype=np.intp)

    across = np.array(
        [
            [4 * pair_of[(i, low + j)] + 2 * s + t for j in range(high) for t in range(2)]
            for i in range(low)
            for s in range(2)
        ],
        dtype=np.intp,
    ).reshape(2 * low, 2 * high)
    return Halves(
        low,
        high,
        columns(0, low),
        columns(low, high),
        across,
        design(low)[:, 4 * len(PAIRS[low][0]) :],
        design(high)[:, 4 * len(PAIRS[high][0]) :],
    )


def estimate_costs(n: int, block: FloatArray, unary: FloatArray) -> FloatArray:
    """(G, C) every labelling's cost for G persons of n ≥ 2 views, summed in a quick order.

    Σ_pairs D[pair, c_i, c_j] + Σ_views U[view, c_view] by :class:`Halves`: the two halves'
    costs and the pairs across them as small matrix products, instead of one (G, 4·pairs +
    2·n) @ (4·pairs + 2·n, 2^n) product (6 persons of 10 views: 1.2 M multiply-adds against
    about 40 k). The order of the sums differs from the exact cost's: rounding only.

    Args:
        block: (G, 4·pairs) D flattened; unary: (G, 2·n) U flattened (view-major).
    """
    h = halves(n)
    table = np.concatenate([block, unary], axis=1)
    low = table[:, h.low_columns] @ design(h.low).T  # (G, 2^low)
    high = table[:, h.high_columns] @ design(h.high).T  # (G, 2^high)
    across = h.one_low @ table[:, h.across] @ h.one_high.T  # (G, 2^low, 2^high)
    total = across + low[:, :, None] + high[:, None, :]
    costs: FloatArray = total.transpose(0, 2, 1).reshape(len(table), -1)  # c = a + 2^low · b
    return costs


def screen(n: int, block: FloatArray, unary: FloatArray) -> IntArray:
    """Each person's labelling when a quick estimate settles it, else −1 (score exactly).

    The cost of labelling c is Σ_pairs D[pair, c_i, c_j] + Σ_views U[view, c_view], linear in
    c's one-hot design, so a few matrix products estimate every cost of every person
    (:func:`estimate_costs`). The estimate sums in another order than the exact cost, so they
    differ by rounding only (about 1e-14 m). When the best estimate beats every other by more
    than :data:`SCREEN_MARGIN_M`, the exact minimum is that labelling and no other: it is
    returned. Otherwise (near-ties, where rounding decides as in the exact enumeration, or an
    estimate that is not finite) −1.

    Args:
        block: (G, 4·pairs) D flattened; unary: (G, 2·n) U flattened (view-major).

    Returns:
        (G,) index of the labelling in :data:`COMBOS` ``[n]``, or −1.
    """
    estimate = estimate_costs(n, block, unary)  # (G, C)
    best = np.argmin(estimate, axis=1)
    rows = np.arange(len(best))
    lowest = estimate[rows, best]
    estimate[rows, best] = np.inf
    runner_up = estimate.min(axis=1)
    settled = np.isfinite(lowest) & (runner_up > lowest + SCREEN_MARGIN_M)
    result: IntArray = np.where(settled, best, -1)
    return result
