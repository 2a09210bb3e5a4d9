"""Weighted fusion: each joint as the weighted mean of the views that have it.

Report A (``shared/papers.md``): sensor k sees joint n at J_kn with confidence C_kn; the fused
joint is ``J_n = Σ_k C_kn·J_kn / Σ_k C_kn``, C the weights of :mod:`skelfuse.fusion.confidence`.
:func:`cauchy_reweight` can then discount views far from that consensus (off by default), and
:func:`carriers` tells which views a fused joint came from.

Shapes: P persons fused at once, each with up to S views (a person with fewer is padded with NaN
views of weight 0, which changes no sum or product), J = 25 joints. Metres, world frame.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_stages
from skelfuse.fusion.confidence import joint_confidence
from skelfuse.fusion.points import finite_points

FloatArray = npt.NDArray[np.float64]
MIN_SHARE: Final = 0.05
"""A view is a source of a fused joint when it carries at least this share of the weight."""


def weighted_mean(joints: FloatArray, weights: FloatArray) -> FloatArray:
    """The confidence-weighted mean of each person's views (report A, eq. 2).

    Args:
        joints: (P, S, J, 3) positions; NaN where a view has no position (it contributes
            nothing whatever its weight).
        weights: (P, S, J) non-negative.

    Returns:
        (P, J, 3) float64; NaN where no view has a position with a positive weight.
    """
    if kernels.enabled():  # the same bits in one compiled loop; the code below is the reference
        return kernels.weighted_mean(joints, weights)
    usable = finite_points(joints) & (weights > 0)
    w = np.where(usable, weights, 0.0)
    total = w.sum(axis=1)
    safe_views = np.where(usable[..., None], joints, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused: FloatArray = (w[..., None] * safe_views).sum(axis=1) / total[..., None]
    fused[total <= 0] = np.nan
    return fused


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


def cauchy_reweight(
    joints: FloatArray, fused: FloatArray, weights: FloatArray, scale_m: float
) -> FloatArray:
    """One Cauchy re-weighting pass: views far from their person's weighted mean count less.

    Args:
        joints: (N, J, 3) views, metres; fused: (N, J, 3) the fused skeleton of each view's
            person; weights: (N, J).
        scale_m: distance at which a view's weight is halved.

    Returns:
        (N, J) weights × ``1 / (1 + (d / scale)²)``, d the view's distance to ``fused``
        (unchanged where d is unknown).
    """
    d = np.linalg.norm(joints - fused, axis=-1)
    factor = np.where(np.isfinite(d), 1.0 / (1.0 + (d / scale_m) ** 2), 1.0)
    result: FloatArray = weights * factor
    return result


def confidence_and_carriers(
    joints: FloatArray, weights: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """:func:`~skelfuse.fusion.confidence.joint_confidence` and :func:`carriers` of the same
    views: with the kernels on, both from one compiled pass (the same bits as the two calls).

    Args:
        joints: (P, S, J, 3) as fused (NaN: no position); weights: (P, S, J) the final weights.

    Returns:
        confidence (P, J) float64 and carried (P, S, J) bool.
    """
    if kernels.enabled():
        return kernels_stages.confidence_and_carriers(joints, weights, MIN_SHARE)
    return joint_confidence(joints, weights), carriers(joints, weights)


def carriers(joints: FloatArray, weights: FloatArray) -> npt.NDArray[np.bool_]:
    """Which views carried each fused joint: at least :data:`MIN_SHARE` of its weight.

    Args:
        joints: (P, S, J, 3) as fused (NaN: no position); weights: (P, S, J) the final weights.

    Returns:
        (P, S, J) bool.
    """
    if kernels.enabled():  # the same bits in one compiled loop; the code below is the reference
        return kernels_stages.confidence_and_carriers(joints, weights, MIN_SHARE)[1]
    final = np.where(finite_points(joints), weights, 0.0)
    total = final.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(total[:, None] > 0, final / total[:, None], 0.0)
    result: npt.NDArray[np.bool_] = (share >= MIN_SHARE) & (final > 0)
    return result
