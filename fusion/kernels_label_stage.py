"""The mirror labels' scoring in the usual step as one compiled call (numba), and what follows
the choice as another.

:func:`skelfuse.fusion.label_scores.scored_labels` chooses every view's labelling and measures
each view's anatomical evidence against it. With every person's last skeleton and facing known
(the usual step) the compiled path was five calls (the range-of-motion factors of both
labellings, the lateral distances, the scores, the evidence) with their arguments' stacks and
gathers: ~100 µs of glue at 4 sensors × 6 people around ~50 µs of loops. Here one call runs the
same loops (:func:`~skelfuse.fusion.anatomy.rom_loop`,
:func:`~skelfuse.fusion.kernels_mirror.lateral_loop`,
:func:`~skelfuse.fusion.kernels_mirror.score_loop`,
:func:`~skelfuse.fusion.kernels_labels.evidence_loop`) on the same values, so the same bits
and the same choices (tests/unit/test_label_scores.py). :func:`settled` does, once the choice is
made (and re-decided), the swap back, the unbiased facings and the gather of the factors as
labelled in one call too.

The loop runs only once :func:`warm_up` has compiled it (or loaded it from numba's cache), so
no frame waits for a compilation; until then, and with the kernels off, the calls one by one
(or numpy) run.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import rom_loop
from skelfuse.fusion.kernels_jit import Warmed, jit, plain
from skelfuse.fusion.kernels_labels import evidence_loop
from skelfuse.fusion.kernels_mirror import Terms, lateral_loop, score_loop

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

warmed = Warmed()
"""Whether :func:`warm_up` has run: see :class:`~skelfuse.fusion.kernels_jit.Warmed`."""


class Scored(NamedTuple):
    """Every view's labelling and what was measured on the way (N views, P persons).

    mirrored: (N,) bool, the labelling chosen; factors: (N, 2, 25) range-of-motion factors of
    each view as reported (0) and swapped (1); forward: (N, 2, 3) each labelling's body
    forward axis; per_view: (N,) each view's evidence against its labelling, in joints;
    evidence: (P,) its sum per person. (``factors``, ``forward``, ``per_view`` and ``evidence``
    None where not computed.)
    """

    mirrored: BoolArray
    factors: FloatArray | None
    forward: FloatArray | None
    per_view: FloatArray | None
    evidence: FloatArray | None


def scored(
    views: FloatArray,
    sensor_positions: FloatArray,
    places: tuple[IntArray, IntArray, IntArray, IntArray],
    known: tuple[FloatArray, FloatArray, IntArray],
    terms: Terms,
    tables: tuple[IntArray, IntArray, IntArray],
    screen: tuple[int, float],
    rom: tuple[float, FloatArray, FloatArray],
) -> Scored:
    """The usual step's labelling of every view, all persons at once.

    Args:
        views: (N, 25, 3) metres, world, each person's consecutive; sensor_positions: (N, 3).
        places: (P + 1,) each person's first view then N, (N,) each view's person, and (K,)
            each pair's first and second view, person by person (the mirror layout).
        known: (P, 3) each person's facing (finite), (P, 25, 3) its last skeleton, and (N,)
            each view's last decision (1, 0, −1 unknown).
        terms: the track, geometry and anatomy weights, the swap prior, the hysteresis (metres)
            and 1.0 when the last decisions count (else 0.0).
        tables: the lateral joints, where each one's other side is among them, and the
            left/right permutation of the 25 joints.
        screen: the view count from which labellings are screened, and the margin.
        rom: the range-of-motion scale (degrees) and the angle limits, low and high (13,).
    """
    points = plain(views)
    total, size = points.shape[0], points.shape[1]
    starts, person_of, first, second = places
    facings, references, previous = known
    scale_deg, low, high = rom
    factors = np.ones((total, 2, size))
    forward = np.empty((total, 2, 3))
    mirrored = np.zeros(total, dtype=np.bool_)
    per_view = np.empty(total)
    evidence = np.empty(len(starts) - 1)
    _scored_loop(
        points,
        plain(sensor_positions),
        (
            plain(starts, np.intp),
            plain(person_of, np.intp),
            plain(first, np.intp),
            plain(second, np.intp),
        ),
        (plain(facings), plain(references), plain(previous, np.intp)),
        terms,
        (plain(tables[0], np.intp), plain(tables[1], np.intp), plain(tables[2], np.intp)),
        (int(screen[0]), float(screen[1])),
        (float(scale_deg), plain(low), plain(high)),
        (mirrored, factors, forward, per_view, evidence),
    )
    return Scored(mirrored, factors, forward, per_view, evidence)


@jit
def _scored_loop(  # pragma: no cover - compiled
    views: FloatArray,
    sensor_positions: FloatArray,
    places: tuple[IntArray, IntArray, IntArray, IntArray],
    known: tuple[FloatArray, FloatArray, IntArray],
    terms: Terms,
    tables: tuple[IntArray, IntArray, IntArray],
    screen: tuple[int, float],
    rom: tuple[float, FloatArray, FloatArray],
    out: tuple[BoolArray, FloatArray, FloatArray, FloatArray, FloatArray],
) -> None:
    mirrored, factors, forward, per_view, evidence = out
    starts, person_of, first, second = places
    facings, references, previous = known
    lateral, swap, permutation = tables
    total, size = views.shape[0], views.shape[1]
    # Both labellings of every view, (N, 2, 25, 3) as rows of (2N, 25, 3): as reported, swapped.
    both = np.empty((total, 2, size, 3))
    for v in range(total):
        for j in range(size):
            for c in range(3):
                both[v, 0, j, c] = views[v, j, c]
                both[v, 1, j, c] = views[v, permutation[j], c]
    rom_loop(
        both.reshape(2 * total, size, 3),
        rom,
        factors.reshape(2 * total, size),
        forward.reshape(2 * total, 3),
        np.empty((2 * total, 13)),
    )
    # Each view's person's last skeleton, and the agreement terms.
    own = np.empty((total, size, 3))
    for v in range(total):
        for j in range(size):
            for c in range(3):
                own[v, j, c] = references[person_of[v], j, c]
    pair = np.empty((len(first), 2, 2))
    to_ref = np.empty((total, 2))
    lateral_loop(views, lateral, swap, first, second, own, np.ones(total, np.bool_), pair, to_ref)
    score_loop(
        views,
        sensor_positions,
        starts,
        facings,
        pair,
        to_ref,
        factors,
        previous,
        terms,
        screen[0],
        screen[1],
        mirrored,
    )
    evidence_loop(factors, mirrored, person_of, per_view, evidence)


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now; a no-op with the kernels off."""
    views = np.zeros((2, 25, 3))
    index = np.arange(20, dtype=np.intp)
    pairs = (np.zeros(1, dtype=np.intp), np.ones(1, dtype=np.intp))
    scored(
        views,
        np.ones((2, 3)),
        (np.array([0, 2]), np.zeros(2, dtype=np.intp), *pairs),
        (np.ones((1, 3)), views[:1], np.zeros(2, dtype=np.intp)),
        (1.0, 0.1, 0.1, 0.01, 0.05, 1.0),
        (index, index, np.arange(25, dtype=np.intp)),
        (6, 1e-9),
        (15.0, np.zeros(13), np.zeros(13)),
    )
    warmed.done = True
