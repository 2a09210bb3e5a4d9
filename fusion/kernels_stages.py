"""Entry points of the compiled kernels of the confidence stage.

Each function here runs a loop compiled with numba (kernels_facing.py, kernels_confidence.py)
for what the confidence code it names computes. Each call passes arrays of the types
:func:`warm_up` compiled for (:func:`~skelfuse.fusion.kernels_jit.plain`), so no frame waits
for a compilation.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import plain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


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
    facing_factors(facing_cosines(views[0], views[1], views[0]), 2.0, 0.1, 0.5)
    index = np.zeros(24, dtype=np.intp)
    body_weights(
        views, np.zeros((2, 25), np.uint8), (0.0, 0.5, 1.0), np.ones((2, 24)), np.ones((2, 25)),
        0.05, (index, index), (index, index),
    )  # fmt: skip
    confidence_and_carriers(views[None], np.ones((1, 2, 25)), 0.05)
