"""Entry points of the compiled kernels of the mirror and confidence stages.

As :mod:`skelfuse.fusion.kernels` for the others: each function here computes what the numpy
code it names computes, the same bits, in a loop compiled with numba (kernels_mirror.py,
kernels_facing.py, kernels_confidence.py); callers use it when
:func:`skelfuse.fusion.kernels.enabled`. Each call passes arrays of the types :func:`warm_up`
compiled for (:func:`~skelfuse.fusion.kernels_jit.plain`), so no frame waits for a compilation.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import plain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


def mirror_scores(
    views: FloatArray,
    sensor_positions: FloatArray,
    places: tuple[IntArray, IntArray, IntArray, IntArray],
    facings: FloatArray,
    references: FloatArray,
    anatomy_factors: FloatArray | None,
    previous: IntArray | None,
    terms: tuple[float, float, float, float, float],
    lateral: tuple[IntArray, IntArray],
    screen: tuple[int, float],
) -> npt.NDArray[np.bool_]:
    """The compiled scoring of :func:`skelfuse.fusion.mirror.choose_labellings` for persons
    whose facing is known (the same choices, from the same bits of every term).

    Args:
        views: (N, 25, 3) metres, world; sensor_positions: (N, 3); places: (P + 1,) each
            person's first view then N, (N,) each view's person, and (K,) each pair's first
            and second view, person by person in ``PAIRS`` order (the frame's layout);
            facings: (P, 3) each person's facing (finite); references: (P, 25, 3) each
            person's last skeleton; anatomy_factors: (N, 2, 25) range-of-motion factors as
            reported and swapped, or None (no anatomy term); previous: (N,) last decisions
            (1, 0, −1 unknown) or None; terms: the track, geometry and anatomy weights, the
            swap prior and the hysteresis (metres); lateral: the lateral joints and where each
            one's other side is among them; screen: the view count from which labellings are
            screened, and the margin.

    Returns:
        (N,) bool, True where a view is mirrored.
    """
    from skelfuse.fusion import kernels_mirror  # imports numba: only when used

    points = plain(views)
    total = points.shape[0]
    starts, person_of, first, second = places
    pair = np.empty((len(first), 2, 2))
    to_ref = np.empty((total, 2))
    kernels_mirror.lateral_loop(
        points,
        plain(lateral[0], np.intp),
        plain(lateral[1], np.intp),
        plain(first, np.intp),
        plain(second, np.intp),
        plain(references[person_of]),
        np.ones(total, dtype=np.bool_),
        pair,
        to_ref,
    )
    track, geometry, anatomy, prior, hysteresis = terms
    weights = (
        float(track), float(geometry), float(anatomy) if anatomy_factors is not None else 0.0,
        float(prior), float(hysteresis), 0.0 if previous is None else 1.0,
    )  # fmt: skip
    mirrored = np.zeros(total, dtype=np.bool_)
    kernels_mirror.score_loop(
        points,
        plain(sensor_positions),
        plain(starts, np.intp),
        plain(facings),
        pair,
        to_ref,
        plain(np.ones((total, 2, 1)) if anatomy_factors is None else anatomy_factors),
        plain(np.full(total, -1) if previous is None else previous, np.intp),
        weights,
        int(screen[0]),
        float(screen[1]),
        mirrored,
    )
    return mirrored


def view_evidence(
    factors: FloatArray, mirrored: npt.NDArray[np.bool_], person_of: IntArray, persons: int
) -> tuple[FloatArray, FloatArray]:
    """The compiled :func:`skelfuse.fusion.label_scores.view_evidence` and its sum per person (the
    same bits as ``np.bincount``).

    Args:
        factors: (N, 2, 25) range-of-motion factors as reported and swapped; mirrored: (N,)
            the labelling chosen; person_of: (N,) each view's person; persons: P.

    Returns:
        per view (N,) and per person (P,), in joints.
    """
    from skelfuse.fusion import kernels_labels  # imports numba: only when used

    per_view = np.empty(len(mirrored))
    evidence = np.empty(persons)
    kernels_labels.evidence_loop(
        plain(factors), plain(mirrored, np.bool_), plain(person_of, np.intp), per_view, evidence
    )
    return per_view, evidence


def facing_cosines(facings: FloatArray, bodies: FloatArray, sensors: FloatArray) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.confidence.facing_cosines`, one facing and body
    position per view (the same bits).

    Args:
        facings: (N, 3) each view's person's facing; bodies: (N, 3) where it stands;
        sensors: (N, 3) each view's sensor; metres, world (NaN: unknown).

    Returns:
        (N,) cosines, NaN where unknown.
    """
    from skelfuse.fusion import kernels_facing  # imports numba: only when used

    out = np.empty(len(facings))
    kernels_facing.cosines_loop(plain(facings), plain(bodies), plain(sensors), out)
    return out


def facing_factors(cosines: FloatArray, power: float, floor: float, back: float) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.confidence.facing_factors` (the same bits)."""
    from skelfuse.fusion import kernels_facing  # imports numba: only when used

    out = np.empty(len(cosines))
    kernels_facing.facing_factors_loop(plain(cosines), float(power), float(floor), float(back), out)
    return out


def body_weights(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    table: tuple[float, float, float],
    references: FloatArray | None,
    rom: FloatArray | None,
    scale_m: float,
    bones: tuple[IntArray, IntArray],
    chain: tuple[IntArray, IntArray],
) -> FloatArray:
    """The compiled :func:`skelfuse.fusion.confidence.body_weights` when every view uses the
    settings' state table (the same bits).

    Args:
        joints: (N, 25, 3) views, metres; states: (N, 25) tracking states; table: the weight
            of NotTracked, Inferred, Tracked; references: (N, 24) reference bone lengths
            (NaN: unknown), or None: no bone-length term; rom: (N, 25) range-of-motion
            factors, or None: no range-of-motion term; scale_m: the bone-length scale;
            bones: each bone's parent and child joint; chain: the joints below SpineBase,
            parents first, and their parents.

    Returns:
        (N, 25) float64 weights.
    """
    from skelfuse.fusion import kernels_confidence  # imports numba: only when used

    points = plain(joints)
    out = np.empty(points.shape[:2])
    flags = np.array([references is not None, rom is not None])
    kernels_confidence.body_loop(
        points,
        plain(states, np.uint8),
        np.array(table, dtype=np.float64),
        plain(np.ones((1, 1)) if references is None else references),
        plain(np.ones((1, 1)) if rom is None else rom),
        flags,
        float(scale_m),
        (plain(bones[0], np.intp), plain(bones[1], np.intp)),
        (plain(chain[0], np.intp), plain(chain[1], np.intp)),
        out,
    )
    return out


def confidence_and_carriers(
    joints: FloatArray, weights: FloatArray, min_share: float
) -> tuple[FloatArray, BoolArray]:
    """The compiled :func:`skelfuse.fusion.confidence.joint_confidence` and
    :func:`skelfuse.fusion.weighted.carriers` in one pass (the same bits).

    Args:
        joints: (P, S, J, 3) each person's views as fused, NaN where a view has no position;
        weights: (P, S, J) the final weights; min_share: the share of a joint's weight a
            view carries at least to be one of its sources.

    Returns:
        confidence (P, J) float64 and carried (P, S, J) bool.
    """
    from skelfuse.fusion import kernels_confidence  # imports numba: only when used

    w = plain(weights)
    confidence = np.empty((w.shape[0], w.shape[2]))
    carried = np.empty(w.shape, dtype=np.bool_)
    kernels_confidence.confidence_loop(plain(joints), w, float(min_share), confidence, carried)
    return confidence, carried


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's kernels (with numba on)."""
    views = np.zeros((2, 25, 3))
    pairs = (np.zeros(1, dtype=np.intp), np.ones(1, dtype=np.intp))
    lateral = (np.arange(20, dtype=np.intp), np.arange(20, dtype=np.intp))
    places = (np.array([0, 2]), np.zeros(2, dtype=np.intp), *pairs)
    mirror_scores(
        views, np.ones((2, 3)), places, np.ones((1, 3)), views[:1], np.ones((2, 2, 25)),
        np.zeros(2, dtype=np.intp), (1.0, 0.1, 0.1, 0.01, 0.05), lateral, (6, 1e-9),
    )  # fmt: skip
    facing_factors(facing_cosines(views[0], views[1], views[0]), 2.0, 0.1, 0.5)
    view_evidence(np.ones((2, 2, 25)), np.zeros(2, bool), np.zeros(2, dtype=np.intp), 1)
    index = np.zeros(24, dtype=np.intp)
    body_weights(
        views, np.zeros((2, 25), np.uint8), (0.0, 0.5, 1.0), np.ones((2, 24)), np.ones((2, 25)),
        0.05, (index, index), (index, index),
    )  # fmt: skip
    confidence_and_carriers(views[None], np.ones((1, 2, 25)), 0.05)
