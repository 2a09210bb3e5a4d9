"""Where each person's views and view pairs are among a frame's views, as index arrays built once
per shape, and the constants of the labellings' screen.

A labelling gives each of a person's n views a label, as reported (0) or swapped (1); there are
C = 2^n. :mod:`skelfuse.fusion.mirror` scores them all; from :data:`SCREEN_FROM_VIEWS` views on,
persons whose facing is known are screened with a quick estimate first.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.intp]
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
