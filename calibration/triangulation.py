"""Multi-view triangulation of 2-D landmarks from calibrated cameras (weighted DLT, numpy only).

API::

    result = triangulate(cameras, image_px, weights=None, *, max_error_px=None, min_views=2)
    result.points_world     (..., 3) metres, world frame; NaN where fewer than min_views views
    result.reprojection_px  (V, ..., ) each view's reprojection error; NaN where it had no
                            observation (it is also given for views dropped as outliers)
    result.views_used       (V, ...) bool, the views the point was solved from

``cameras``: V :class:`calibration.camera.Camera`. ``image_px``: (V, ..., 2) pixels as detected
(distortion is removed here), NaN where a view did not see the point; ``...`` is any batch
shape, e.g. (frames, joints). ``weights``: (V, ...) ≥ 0, e.g. a detector's visibility; a view
with weight 0 is not used. Each view contributes its two DLT rows scaled by its weight (rows
normalised first, so the weight is the view's share, not an artefact of its pose).

``max_error_px``: while a point has more than ``min_views`` views and its worst reprojection
error exceeds this, that view is dropped and the point solved again (one view per round).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.camera import Camera
from skelfuse.calibration.errors import InvalidInput

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class Triangulation:
    """Result of :func:`triangulate` (shapes in the module docstring)."""

    points_world: FloatArray
    reprojection_px: FloatArray
    views_used: BoolArray


def triangulate(
    cameras: Sequence[Camera],
    image_px: npt.ArrayLike,
    weights: npt.ArrayLike | None = None,
    *,
    max_error_px: float | None = None,
    min_views: int = 2,
) -> Triangulation:
    """Triangulate every point seen by at least ``min_views`` cameras (see the module docstring).

    Raises:
        InvalidInput: fewer than 2 cameras, ``image_px`` not (V, ..., 2) for V cameras,
            ``weights`` not (V, ...) or negative/NaN, ``min_views`` < 2, ``max_error_px`` ≤ 0.
    """
    uv = np.asarray(image_px, dtype=np.float64)
    n_views = len(cameras)
    if n_views < 2:
        raise InvalidInput(f"triangulation needs at least 2 cameras, got {n_views}")
    if uv.ndim < 2 or uv.shape[0] != n_views or uv.shape[-1] != 2:
        raise InvalidInput(
            f"image_px: expected shape ({n_views}, ..., 2) for {n_views} cameras, got {uv.shape}"
        )
    if weights is None:
        w = np.ones(uv.shape[:-1])
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != uv.shape[:-1]:
            raise InvalidInput(f"weights: expected shape {uv.shape[:-1]}, got {w.shape}")
        if np.isnan(w).any() or (w < 0).any():
            raise InvalidInput("weights must be non-negative numbers (0 leaves a view out)")
    if min_views < 2:
        raise InvalidInput(f"min_views must be at least 2, got {min_views}")
    if max_error_px is not None and not max_error_px > 0:
        raise InvalidInput(f"max_error_px must be positive, got {max_error_px}")

    seen = np.isfinite(uv).all(axis=-1)
    use = seen & (w > 0)
    normalized = np.stack([cam.normalized(uv[i]) for i, cam in enumerate(cameras)])
    projections = np.stack([cam.T_opencv_from_world[:3] for cam in cameras])  # (V, 3, 4)
    rows = _dlt_rows(normalized, projections)  # (V, ..., 2, 4), unit rows
    while True:
        points = _solve(rows, np.where(use, w, 0.0), use.sum(axis=0) >= min_views)
        errors = _reprojection(cameras, points, uv)
        if max_error_px is None:
            break
        worst = np.where(use, errors, -np.inf).argmax(axis=0)
        worst_error = np.take_along_axis(np.where(use, errors, -np.inf), worst[None], 0)[0]
        drop = (worst_error > max_error_px) & (use.sum(axis=0) > min_views)
        if not drop.any():
            break
        use = use & ~((np.arange(n_views).reshape((-1,) + (1,) * drop.ndim) == worst) & drop)
    return Triangulation(points, errors, use & np.isfinite(points).all(axis=-1))


def _dlt_rows(normalized: FloatArray, projections: FloatArray) -> FloatArray:
    """(V, ..., 2, 4) DLT rows ``x·P3 − P1`` and ``y·P3 − P2``, each scaled to unit length."""
    extra = normalized.ndim - 2
    p = projections.reshape((projections.shape[0],) + (1,) * extra + (3, 4))
    x = normalized[..., 0, None]
    y = normalized[..., 1, None]
    row_x = x * p[..., 2, :] - p[..., 0, :]
    row_y = y * p[..., 2, :] - p[..., 1, :]
    rows = np.stack([row_x, row_y], axis=-2)
    norms = np.linalg.norm(rows, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norms > 0, rows / norms, 0.0)


def _solve(rows: FloatArray, weights: FloatArray, solvable: BoolArray) -> FloatArray:
    """Least-squares homogeneous solution of the weighted rows for every point: (..., 3)."""
    weighted = np.nan_to_num(rows) * weights[..., None, None]  # unseen views: zero rows
    stacked = np.moveaxis(weighted, 0, -3)  # (..., V, 2, 4)
    a = stacked.reshape(stacked.shape[:-3] + (-1, 4))
    # The smallest eigenvector of AᵀA (4×4) is the SVD's last right-singular vector.
    _, vectors = np.linalg.eigh(np.swapaxes(a, -1, -2) @ a)
    homogeneous = vectors[..., :, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        points = homogeneous[..., :3] / homogeneous[..., 3:]
    return np.where(solvable[..., None] & np.isfinite(points), points, np.nan)


def _reprojection(cameras: Sequence[Camera], points: FloatArray, uv: FloatArray) -> FloatArray:
    """(V, ...) pixel distance of each camera's projection of ``points`` from its observation."""
    projected = np.stack([cam.project(points) for cam in cameras])
    return np.asarray(np.linalg.norm(projected - uv, axis=-1), dtype=np.float64)
