"""Fusion math: pure functions on arrays, no I/O.

Report A (``shared/papers.md``): sensor k sees joint n at J_kn with confidence C_kn; the fused
joint is the confidence-weighted mean ``J_n = Σ_k C_kn·J_kn / Σ_k C_kn`` with C from the tracking
state (NotTracked 0, Inferred 0.3, Tracked 0.7). The body-based terms (bone length, range of
motion, facing) multiply into the same weights in a later version.

Shapes: S views of one person, J = 25 joints. Positions in metres, world frame.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from protocol.skeleton import JOINT_COUNT, JointId

FloatArray = npt.NDArray[np.float64]

TRUNK_JOINTS: Final = np.array(
    [JointId.SPINE_BASE, JointId.SPINE_MID, JointId.SPINE_SHOULDER, JointId.NECK, JointId.HEAD]
)
"""Joints on the body's midline: the same whatever a sensor thinks is left or right."""


def state_weights(states: npt.ArrayLike, table: tuple[float, float, float]) -> FloatArray:
    """Per-joint weights from tracking states.

    Args:
        states: (S, J) uint8 TrackingState values.
        table: weight of NotTracked, Inferred, Tracked.

    Returns:
        (S, J) float64 weights.
    """
    return np.asarray(table, dtype=np.float64)[np.asarray(states, dtype=np.intp)]


def fuse_views(joints: npt.ArrayLike, weights: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Confidence-weighted mean of S views of one person (report A, eq. 2).

    Args:
        joints: (S, J, 3) positions, metres, world frame; NaN where a view has no position.
        weights: (S, J) non-negative weights; a NaN position contributes nothing whatever its
            weight.

    Returns:
        fused: (J, 3) float64; NaN where no view has a positive weight.
        confidence: (J,) float64 in [0, 1]: ``1 − Π_k (1 − w_k)`` with weights clipped to
            [0, 1], the chance that at least one view is right if each is right with
            probability w_k. 0 exactly where ``fused`` is NaN.
    """
    views = np.asarray(joints, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if views.ndim != 3 or views.shape[2] != 3 or w.shape != views.shape[:2]:
        raise ValueError(
            f"expected joints (S, J, 3) and weights (S, J), got {views.shape} and {w.shape}"
        )
    usable = np.isfinite(views).all(axis=2) & (w > 0)
    w = np.where(usable, w, 0.0)
    total = w.sum(axis=0)
    safe_views = np.where(usable[..., None], views, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = (w[..., None] * safe_views).sum(axis=0) / total[:, None]
    fused[total <= 0] = np.nan
    confidence = 1.0 - np.prod(1.0 - np.clip(w, 0.0, 1.0), axis=0)
    confidence[total <= 0] = 0.0
    return fused, confidence


def trunk_distance(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Mean distance between the midline joints two skeletons both have (metres).

    Used to decide whether two views (or a view and a track) are the same person. Midline
    joints make it immune to a sensor swapping left and right. ``inf`` with nothing in common.

    Args:
        a, b: (25, 3) joints, metres, same frame; NaN where unknown.
    """
    pa = np.asarray(a, dtype=np.float64)[TRUNK_JOINTS]
    pb = np.asarray(b, dtype=np.float64)[TRUNK_JOINTS]
    both = np.isfinite(pa).all(axis=1) & np.isfinite(pb).all(axis=1)
    if both.sum() < 2:
        return float("inf")
    return float(np.linalg.norm(pa[both] - pb[both], axis=1).mean())


def mpjpe(estimate: npt.ArrayLike, truth: npt.ArrayLike) -> tuple[float, int]:
    """Mean per-joint position error over the joints the estimate has (metres), and how many.

    Args:
        estimate, truth: (..., 25, 3) positions in the same frame; NaN in ``estimate`` means the
            joint was not reported and is left out (the count tells how many were scored).
    """
    est = np.asarray(estimate, dtype=np.float64).reshape(-1, JOINT_COUNT, 3)
    ref = np.asarray(truth, dtype=np.float64).reshape(-1, JOINT_COUNT, 3)
    err = np.linalg.norm(est - ref, axis=-1)
    present = np.isfinite(err)
    if not present.any():
        return float("nan"), 0
    return float(err[present].mean()), int(present.sum())
