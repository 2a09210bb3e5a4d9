"""Closed-form rigid fit between corresponding 3-D points (Kabsch), and pose-error helpers.

The rotation itself is :func:`protocol.transform.kabsch_rotation` (the BVH exporter fits bone
rotations with it too); this module adds weights, centroids, the translation, degeneracy checks
and residuals.

All computations are float64. Frames follow ``protocol.transform``: ``T_dst_from_src`` maps
points expressed in frame ``src`` into frame ``dst`` (``p_dst = T_dst_from_src @ p_src``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import DegenerateGeometry, InvalidInput, NotEnoughCorrespondences
from skelfuse.protocol.transform import Matrix4, kabsch_rotation

FloatArray = npt.NDArray[np.float64]

MIN_SPREAD_M: Final = 1e-3
"""Default tolerance for :func:`fit_rigid`: the weighted RMS distance of the source points from
their best-fit line must be at least this (1 mm), otherwise they are called collinear."""


@dataclass(frozen=True, slots=True)
class RigidFit:
    """Result of :func:`fit_rigid`.

    ``T_dst_from_src``: (4, 4) float64 proper rigid transform. ``rmse_m``: weighted RMS of the
    residuals (metres). ``residuals_m``: (N,) float64 distance of each transformed source point
    from its destination point (metres).
    """

    T_dst_from_src: Matrix4
    rmse_m: float
    residuals_m: FloatArray


def as_points(points: npt.ArrayLike, name: str) -> FloatArray:
    """``points`` as an (N, 3) float64 array of finite values, or :class:`InvalidInput`."""
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise InvalidInput(f"{name}: expected an (N, 3) array of points, got shape {array.shape}")
    if not np.isfinite(array).all():
        bad = int((~np.isfinite(array).all(axis=1)).sum())
        raise InvalidInput(
            f"{name}: {bad} of {len(array)} points contain NaN or inf; drop missing points "
            "before fitting"
        )
    return array


def fit_rigid(
    src: npt.ArrayLike,
    dst: npt.ArrayLike,
    weights: npt.ArrayLike | None = None,
    *,
    min_spread_m: float = MIN_SPREAD_M,
) -> RigidFit:
    """Least-squares rigid transform mapping ``src`` onto ``dst`` (weighted Kabsch).

    Minimises ``Σ w_i ‖R·src_i + t − dst_i‖²`` over proper rotations R (det +1) and t.

    Args:
        src: (N, 3) points in the source frame, metres.
        dst: (N, 3) corresponding points in the destination frame, metres.
        weights: (N,) non-negative weights (default all 1); points with weight 0 are ignored
            by the fit but still get a residual.
        min_spread_m: the weighted RMS distance of the source points from their best-fit line
            (and of the destination points) must reach this, else the pairs are collinear.

    Returns:
        :class:`RigidFit` with ``T_dst_from_src``.

    Raises:
        InvalidInput: wrong shapes, NaN/inf, negative or all-zero weights.
        NotEnoughCorrespondences: fewer than 3 pairs with a positive weight.
        DegenerateGeometry: coincident or collinear points (spread below ``min_spread_m``).
    """
    p = as_points(src, "src")
    q = as_points(dst, "dst")
    if p.shape != q.shape:
        raise InvalidInput(f"src and dst must have the same shape, got {p.shape} and {q.shape}")
    if weights is None:
        w = np.ones(len(p))
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (len(p),):
            raise InvalidInput(f"weights: expected shape ({len(p)},), got {w.shape}")
        if not np.isfinite(w).all() or (w < 0).any():
            raise InvalidInput("weights must be finite and non-negative")
    used = int((w > 0).sum())
    if used < 3:
        raise NotEnoughCorrespondences(
            f"got {used} corresponding point pair(s) with a positive weight; a rigid transform "
            "needs at least 3 non-collinear pairs (4 or more, spread out, are better)"
        )
    w_sum = float(w.sum())
    c_p = (w[:, None] * p).sum(axis=0) / w_sum
    c_q = (w[:, None] * q).sum(axis=0) / w_sum
    sw = np.sqrt(w / w_sum)[:, None]
    p0 = (p - c_p) * sw
    q0 = (q - c_q) * sw
    for name, centred in (("src", p0), ("dst", q0)):
        spread = np.linalg.svd(centred, compute_uv=False)
        if spread[0] < min_spread_m:
            raise DegenerateGeometry(
                f"{name}: the {used} points coincide (RMS spread {spread[0] * 1000:.2f} mm < "
                f"{min_spread_m * 1000:.2f} mm); pick points that are far apart"
            )
        if spread[1] < min_spread_m:
            raise DegenerateGeometry(
                f"{name}: the {used} points are collinear (RMS distance from their common line "
                f"{spread[1] * 1000:.2f} mm < {min_spread_m * 1000:.2f} mm); add a point off "
                "that line"
            )
    rotation = kabsch_rotation(p0, q0)
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = c_q - rotation @ c_p
    residuals = np.linalg.norm(p @ rotation.T + transform[:3, 3] - q, axis=1)
    rmse = float(np.sqrt((w * residuals**2).sum() / w_sum))
    return RigidFit(transform, rmse, residuals)


def rotation_angle_deg(rotation: npt.ArrayLike) -> float:
    """Angle (degrees, 0..180) of a 3×3 rotation matrix (or the rotation part of a 4×4)."""
    r = np.asarray(rotation, dtype=np.float64)[:3, :3]
    cos = (float(np.trace(r)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def pose_error(T_est: npt.ArrayLike, T_true: npt.ArrayLike) -> tuple[float, float]:
    """Rotation error (degrees) and translation error (millimetres) of a pose estimate.

    Both are (4, 4) ``T_a_from_b`` for the same frames a, b. The rotation error is the angle of
    ``R_true⁻¹·R_est``; the translation error is ``‖t_est − t_true‖`` (the position of frame b's
    origin in frame a).
    """
    est = np.asarray(T_est, dtype=np.float64)
    true = np.asarray(T_true, dtype=np.float64)
    rot = rotation_angle_deg(true[:3, :3].T @ est[:3, :3])
    trans = float(np.linalg.norm(est[:3, 3] - true[:3, 3])) * 1000.0
    return rot, trans
