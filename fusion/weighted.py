"""Weighted fusion: each joint as the weighted mean of the views that have it.

Report A (``shared/papers.md``): sensor k sees joint n at J_kn with confidence C_kn; the fused
joint is ``J_n = Σ_k C_kn·J_kn / Σ_k C_kn``, C the weights of :mod:`skelfuse.fusion.confidence`.
:func:`carriers` tells which views a fused joint came from (the Cauchy pass that can discount
views far from that consensus is :mod:`skelfuse.fusion.weigh`'s).

Shapes: P persons fused at once, each with up to S views (a person with fewer is padded with NaN
views of weight 0, which changes no sum or product), J = 25 joints. Metres, world frame.

:func:`weighted_mean` is one loop compiled with numba (:func:`weighted_loop`): per joint, the
sums over the views start from 0 and add view after view, a view counting where its point is
finite and its weight positive. :func:`warm_up` compiles it (or loads numba's cache) at start.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.confidence import confidence_loop, joint_confidence
from skelfuse.jit import jit, plain

FloatArray = npt.NDArray[np.float64]
MIN_SHARE: Final = 0.05
"""A view is a source of a fused joint when it carries at least this share of the weight."""


def weighted_mean(joints: FloatArray, weights: FloatArray) -> FloatArray:
    """The confidence-weighted mean of each person's views (report A, eq. 2).

    Args:
        joints: (P, S, J, 3) positions; NaN where a view has no position (it contributes
            nothing whatever its weight).
        weights: (P, S, J) non-negative (negative or NaN counts as 0); broadcast to that shape.

    Returns:
        (P, J, 3) float64; NaN where no view has a position with a positive weight.
    """
    points = plain(joints)
    if weights.shape != points.shape[:3]:
        weights = np.broadcast_to(weights, points.shape[:3])
    out = np.empty((points.shape[0], points.shape[2], 3))
    weighted_loop(points, plain(weights), out)
    return out


@jit
def weighted_loop(joints: FloatArray, weights: FloatArray, out: FloatArray) -> None:
    """Fill ``out`` (P, J, 3) with the weighted mean of ``joints`` (P, S, J, 3) under
    ``weights`` (P, S, J): a view counts where its point is finite and its weight positive;
    NaN where no view counts."""
    for p in range(joints.shape[0]):
        for j in range(joints.shape[2]):
            total = 0.0
            s0 = s1 = s2 = 0.0
            for s in range(joints.shape[1]):
                x0, x1, x2 = joints[p, s, j, 0], joints[p, s, j, 1], joints[p, s, j, 2]
                weight = weights[p, s, j]
                usable = (
                    math.isfinite(x0) and math.isfinite(x1) and math.isfinite(x2) and weight > 0
                )
                if not usable:
                    weight, x0, x1, x2 = 0.0, 0.0, 0.0, 0.0
                total += weight
                s0 += weight * x0
                s1 += weight * x1
                s2 += weight * x2
            if total <= 0:
                out[p, j, 0] = out[p, j, 1] = out[p, j, 2] = math.nan
            else:
                out[p, j, 0], out[p, j, 1], out[p, j, 2] = s0 / total, s1 / total, s2 / total


def fuse_views(joints: npt.ArrayLike, weights: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """One person's views fused, with the confidence apps receive.

    Args:
        joints: (S, J, 3) positions, metres, world frame; NaN where a view has no position.
        weights: (S, J) non-negative weights.

    Returns:
        fused (J, 3) as :func:`weighted_mean`, and its
        :func:`~skelfuse.fusion.confidence.joint_confidence` (J,).

    Raises:
        ValueError: on shapes other than (S, J, 3) and (S, J).
    """
    views = np.asarray(joints, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if views.ndim != 3 or views.shape[2] != 3 or w.shape != views.shape[:2]:
        raise ValueError(
            f"expected joints (S, J, 3) and weights (S, J), got {views.shape} and {w.shape}"
        )
    return weighted_mean(views[None], w[None])[0], joint_confidence(views[None], w[None])[0]


def confidence_and_carriers(
    joints: FloatArray, weights: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """:func:`~skelfuse.fusion.confidence.joint_confidence` and :func:`carriers` of the same
    views, from one pass (:func:`~skelfuse.fusion.confidence.confidence_loop`).

    Args:
        joints: (P, S, J, 3) as fused (NaN: no position); weights: (P, S, J) the final weights.

    Returns:
        confidence (P, J) float64 and carried (P, S, J) bool.
    """
    w = plain(weights)
    confidence = np.empty((w.shape[0], w.shape[2]))
    carried = np.empty(w.shape, dtype=np.bool_)
    confidence_loop(plain(joints), w, MIN_SHARE, confidence, carried)
    return confidence, carried


def carriers(joints: FloatArray, weights: FloatArray) -> npt.NDArray[np.bool_]:
    """Which views carried each fused joint: at least :data:`MIN_SHARE` of its weight (the
    weight of the views with a position).

    Args:
        joints: (P, S, J, 3) as fused (NaN: no position); weights: (P, S, J) the final weights.

    Returns:
        (P, S, J) bool.
    """
    return confidence_and_carriers(joints, weights)[1]


def warm_up() -> None:
    """Compile (or load from numba's cache) the weighted mean's loop now."""
    weighted_mean(np.zeros((1, 2, 25, 3)), np.ones((1, 2, 25)))
