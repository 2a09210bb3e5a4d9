"""Steps 5–6 of the usual fusion step as one compiled call (numba).

:func:`skelfuse.fusion.weigh.weigh_and_fuse` weighs every view's joints and fuses each person's
views: the body terms, a first fusion for where each person stands, each view's facing factor,
the weighted fusion, the confidence and the carriers. In numpy and the separate kernels that is
a dozen calls with their arguments' gathers and pads, ~140 µs at 4 sensors × 6 people, for
~20 µs of arithmetic. Here one call runs the same loops on the same values:
:func:`~skelfuse.fusion.kernels_confidence.body_loop`,
:func:`~skelfuse.fusion.kernels_weighted.weighted_loop` on the views padded as
:meth:`~skelfuse.fusion.batch.ViewBatch.pad` pads them (NaN joints, weight 0),
:func:`~skelfuse.fusion.kernels_facing.cosines_loop`,
:func:`~skelfuse.fusion.kernels_facing.facing_factors_loop` and
:func:`~skelfuse.fusion.kernels_confidence.confidence_loop`, so the same bits
(tests/unit/test_weigh.py).

The first fusion is of SpineBase alone: where a person stands is all the usual step takes
from it, and a joint's weighted mean does not depend on the other joints'. A person whose
fused SpineBase is unknown stands at the mean of its views' instead; that rare step is left to
the general code (the call says so and writes nothing else it returns).

The loop runs only once :func:`warm_up` has compiled it (or loaded it from numba's cache), so
no frame waits for a compilation; until then, and with the kernels off, the general code runs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_confidence import body_loop, confidence_loop
from skelfuse.fusion.kernels_facing import cosines_loop, facing_factors_loop
from skelfuse.fusion.kernels_jit import Warmed, jit, plain
from skelfuse.fusion.kernels_weighted import weighted_loop

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

_NOT_USED = np.ones((1, 1))
"""What the loop gets for a term that is off (it reads nothing of it; never written)."""
warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


class Weighed(NamedTuple):
    """What steps 5–6 give the rest of the step (P persons, N views, S the widest person).

    weights: (N, 25) each view's final per-joint weights; fused: (P, 25, 3) metres, world, NaN
    where no view counts; cosines: (N,) each view's facing cosine (NaN: unknown); confidence:
    (P, 25) in [0, 1]; carried: (P, S, 25) which views carried each fused joint.
    """

    weights: FloatArray
    fused: FloatArray
    cosines: FloatArray
    confidence: FloatArray
    carried: BoolArray


def weigh_and_fuse(
    body: tuple[FloatArray, npt.NDArray[np.uint8], FloatArray | None, FloatArray | None],
    terms: tuple[tuple[float, float, float], float, tuple[IntArray, IntArray]],
    chain: tuple[IntArray, IntArray],
    places: tuple[IntArray, int],
    facings: FloatArray,
    sensors: FloatArray,
    facing_model: tuple[float, float, float],
    min_share: float,
) -> Weighed | None:
    """Steps 5–6 for views labelled already, each person's facing known, one facing model and
    the settings' state table for every view (the usual step); None (nothing computed) where a
    person's fused SpineBase is unknown.

    Args:
        body: joints (N, 25, 3) metres, world; states (N, 25) tracking states; references
            (P, 24) each person's reference bone lengths (metres, NaN: unknown) or None (no
            bone-length term; none either where every length is unknown, as
            :func:`~skelfuse.fusion.confidence.body_weights` is called); rom (N, 25)
            range-of-motion factors or None (no such term).
        terms: the state table (NotTracked, Inferred, Tracked), the bone-length scale (metres)
            and each bone's parent and child joint.
        chain: the joints below SpineBase, parents first, and their parents.
        places: (P + 1,) each person's first view, then N (persons' views consecutive), and
            the most views a person has (S).
        facings: (P, 3) each person's facing, horizontal unit vectors (NaN: unknown).
        sensors: (N, 3) each view's sensor position, metres, world (NaN rows: unknown).
        facing_model: (power, floor, back factor) of the facing term.
        min_share: the share of a joint's weight a view carries at least to be a carrier.
    """
    joints, states, references, rom = body
    table, scale_m, bones = terms
    points = plain(joints)
    count = points.shape[0]
    first, widest = plain(places[0], np.intp), int(places[1])
    persons = len(first) - 1
    weights = np.empty((count, points.shape[1]))
    fused = np.empty((persons, points.shape[1], 3))
    cosines = np.empty(count)
    confidence = np.empty((persons, points.shape[1]))
    carried = np.empty((persons, widest, points.shape[1]), dtype=np.bool_)
    done = _weigh_loop(
        points,
        plain(states, np.uint8),
        (float(table[0]), float(table[1]), float(table[2])),
        _NOT_USED if references is None else plain(references),
        _NOT_USED if rom is None else plain(rom),
        (references is not None, rom is not None),
        float(scale_m),
        (plain(bones[0], np.intp), plain(bones[1], np.intp)),
        (plain(chain[0], np.intp), plain(chain[1], np.intp)),
        first,
        widest,
        plain(facings),
        plain(sensors),
        np.array(facing_model, dtype=np.float64),
        float(min_share),
        (weights, fused, cosines, confidence, carried),
    )
    return Weighed(weights, fused, cosines, confidence, carried) if done else None


@jit
def _weigh_loop(  # pragma: no cover - compiled
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    table_values: tuple[float, float, float],
    references: FloatArray,
    rom: FloatArray,
    terms: tuple[bool, bool],
    scale_m: float,
    bones: tuple[IntArray, IntArray],
    chain: tuple[IntArray, IntArray],
    starts: IntArray,
    widest: int,
    facings: FloatArray,
    sensors: FloatArray,
    facing_model: FloatArray,
    min_share: float,
    out: tuple[FloatArray, FloatArray, FloatArray, FloatArray, BoolArray],
) -> bool:
    weights, fused, cosines, confidence, carried = out
    table = np.empty(3)  # (scalars in: an array argument costs a µs to build and pass)
    table[0], table[1], table[2] = table_values
    flags = np.empty(2, dtype=np.bool_)
    flags[0], flags[1] = terms
    count, size = joints.shape[0], joints.shape[1]
    persons = len(starts) - 1
    # Each view's person's reference lengths; the term is off where no length is known.
    known = False
    for p in range(references.shape[0]):
        for b in range(references.shape[1]):
            known = known or math.isfinite(references[p, b])
    flags[0] = flags[0] and known
    per_view = np.empty((count, references.shape[1]))
    if flags[0]:
        for p in range(persons):
            for v in range(starts[p], starts[p + 1]):
                per_view[v] = references[p]
    body_loop(joints, states, table, per_view, rom, flags, scale_m, bones, chain, weights)
    # The views padded per person as ViewBatch.pad pads them: NaN joints, weight 0.
    padded = np.full((persons, widest, size, 3), np.nan)
    padded_weights = np.zeros((persons, widest, size))
    for p in range(persons):
        for s in range(starts[p + 1] - starts[p]):
            v = starts[p] + s
            for j in range(size):
                padded_weights[p, s, j] = weights[v, j]
                for c in range(3):
                    padded[p, s, j, c] = joints[v, j, c]
    # Where each person stands: its fused SpineBase under the body weights.
    spine = np.empty((persons, 1, 3))
    weighted_loop(padded[:, :, :1], padded_weights[:, :, :1], spine)
    for p in range(persons):
        if not (
            math.isfinite(spine[p, 0, 0])
            and math.isfinite(spine[p, 0, 1])
            and math.isfinite(spine[p, 0, 2])
        ):
            return False  # it stands at its views' mean SpineBase: the general code's case
    # Each view's facing cosine and factor, its person's facing and position gathered.
    gathered_facings = np.empty((count, 3))
    stands = np.empty((count, 3))
    for p in range(persons):
        for v in range(starts[p], starts[p + 1]):
            for c in range(3):
                gathered_facings[v, c] = facings[p, c]
                stands[v, c] = spine[p, 0, c]
    cosines_loop(gathered_facings, stands, sensors, cosines)
    factors = np.empty(count)
    facing_factors_loop(cosines, facing_model[0], facing_model[1], facing_model[2], factors)
    for p in range(persons):
        for s in range(starts[p + 1] - starts[p]):
            v = starts[p] + s
            for j in range(size):
                weights[v, j] = weights[v, j] * factors[v]
                padded_weights[p, s, j] = weights[v, j]
    weighted_loop(padded, padded_weights, fused)
    confidence_loop(padded, padded_weights, min_share, confidence, carried)
    return True


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now; a no-op with the kernels off."""
    index = np.zeros(24, dtype=np.intp)
    views = np.zeros((2, 25, 3))
    weigh_and_fuse(
        (views, np.zeros((2, 25), np.uint8), np.ones((1, 24)), np.ones((2, 25))),
        ((0.0, 0.5, 1.0), 0.05, (index, index)),
        (index, index),
        (np.array([0, 2]), 2),
        np.ones((1, 3)),
        np.ones((2, 3)),
        (2.0, 0.1, 0.5),
        0.05,
    )
    warmed.done = True
