"""Perspective-n-point in numpy: where a metric point set sits in front of a pinhole camera.

One RGB camera sees a person's landmarks in pixels, and a pose model (MediaPipe) also gives the
same landmarks in metres around the hips ("world landmarks", axes tied to the camera, no
translation). Finding the rotation R and translation t with ``pixels ≈ project(R·X + t)`` places
the body in the camera frame: the depth comes from the model's body size against the image's.

- :func:`solve_translation`: R fixed to identity (the model's axes already are the camera's),
  three unknowns: a linear least-squares start, then Levenberg-Marquardt on the reprojection
  error in pixels.
- :func:`solve_pose`: R and t (six unknowns), Levenberg-Marquardt from the translation-only
  answer. The same minimum as ``cv2.solvePnP(..., flags=SOLVEPNP_ITERATIVE)`` with unit weights
  (compared in bench/mono/source.py in the mono environment, where cv2 is), without needing cv2.

Frames: OpenCV camera frame (+X right, +Y down, +Z forward, metres) for model points and the
result; pixels as :class:`skelfuse.geometry.pinhole.Intrinsics` has them. Weights (e.g.
MediaPipe's visibility) scale each point's squared residual; a zero weight drops the point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.geometry.pinhole import Intrinsics

FloatArray = npt.NDArray[np.float64]

MIN_DEPTH_M: Final = 0.05
"""A placement that puts any used point nearer than this (or behind the camera) is refused."""


class PnPError(ValueError):
    """No placement: too few usable points, or no solution in front of the camera."""


@dataclass(frozen=True, slots=True)
class Placement:
    """``p_camera = rotation @ p_model + translation`` (OpenCV camera frame, metres).

    rotation: (3, 3) proper rotation; translation: (3,) metres. rms_px: the root of the
    weighted mean squared reprojection error, pixels. iterations: Levenberg-Marquardt steps taken.
    """

    rotation: FloatArray
    translation: FloatArray
    rms_px: float
    iterations: int

    def apply(self, points: npt.ArrayLike) -> FloatArray:
        """(..., 3) model points → camera frame, metres."""
        p = np.asarray(points, dtype=np.float64)
        out: FloatArray = p @ self.rotation.T + self.translation
        return out


def solve_translation(
    model_m: npt.ArrayLike,
    pixels: npt.ArrayLike,
    intrinsics: Intrinsics,
    weights: npt.ArrayLike | None = None,
    max_iterations: int = 10,
) -> Placement:
    """The translation that best projects ``model_m`` (axes already the camera's) onto ``pixels``.

    Args:
        model_m: (N, 3) metres, OpenCV camera axes, any origin (e.g. hip-centred).
        pixels: (N, 2) where the camera sees them.
        intrinsics: the camera's.
        weights: (N,) non-negative, or None for all 1. Points with weight 0 or a non-finite
            coordinate are not used.
        max_iterations: Levenberg-Marquardt steps at most.

    Returns:
        A :class:`Placement` whose rotation is the identity.

    Raises:
        PnPError: fewer than 3 usable points, or the best fit is not in front of the camera.
        ValueError: on mismatched shapes.
    """
    x, u, w = _usable(model_m, pixels, weights, minimum=3)
    t = _linear_translation(x, u, w, intrinsics)
    return _refine(x, u, w, intrinsics, np.eye(3), t, max_iterations, rotate=False)


def solve_pose(
    model_m: npt.ArrayLike,
    pixels: npt.ArrayLike,
    intrinsics: Intrinsics,
    weights: npt.ArrayLike | None = None,
    max_iterations: int = 30,
    initial: Placement | None = None,
) -> Placement:
    """Rotation and translation that best project ``model_m`` onto ``pixels``.

    Starts from ``initial`` (e.g. the previous frame's) or from :func:`solve_translation` with
    R = I, which suits model points whose axes are roughly the camera's (MediaPipe's world
    landmarks); a model turned far from the camera would need a better start.

    Args: as :func:`solve_translation`, plus initial: where to start, or None.

    Raises:
        PnPError: fewer than 4 usable points, or the best fit is not in front of the camera.
        ValueError: on mismatched shapes.
    """
    x, u, w = _usable(model_m, pixels, weights, minimum=4)
    if initial is None:
        rotation, t = np.eye(3), _linear_translation(x, u, w, intrinsics)
        t = _refine(x, u, w, intrinsics, rotation, t, 10, rotate=False).translation
    else:
        rotation, t = initial.rotation, initial.translation
    return _refine(x, u, w, intrinsics, rotation, t, max_iterations, rotate=True)


def rotation_vector_to_matrix(omega: npt.ArrayLike) -> FloatArray:
    """Rodrigues: the rotation by ``|omega|`` radians about ``omega`` (3,) → (3, 3)."""
    w = np.asarray(omega, dtype=np.float64)
    angle = float(np.linalg.norm(w))
    k = _skew(w)
    if angle < 1e-12:
        small: FloatArray = np.eye(3) + k
        return small
    k /= angle
    r: FloatArray = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
    return r


def _usable(
    model_m: npt.ArrayLike, pixels: npt.ArrayLike, weights: npt.ArrayLike | None, minimum: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    x = np.asarray(model_m, dtype=np.float64)
    u = np.asarray(pixels, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or u.shape != (len(x), 2):
        raise ValueError(f"expected model (N, 3) and pixels (N, 2), got {x.shape} and {u.shape}")
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(x),):
        raise ValueError(f"expected weights ({len(x)},), got {w.shape}")
    keep = np.isfinite(x).all(axis=1) & np.isfinite(u).all(axis=1) & np.isfinite(w) & (w > 0)
    if int(keep.sum()) < minimum:
        raise PnPError(f"{int(keep.sum())} usable points, need at least {minimum}")
    return x[keep], u[keep], w[keep]


def _linear_translation(x: FloatArray, u: FloatArray, w: FloatArray, k: Intrinsics) -> FloatArray:
    """Weighted least squares of fx·(X+tx) = du·(Z+tz), fy·(Y+ty) = dv·(Z+tz) (du = u − cx)."""
    du, dv = u[:, 0] - k.cx, u[:, 1] - k.cy
    zeros = np.zeros(len(x))
    a = np.concatenate(
        [
            np.stack([np.full(len(x), k.fx), zeros, -du], axis=1),
            np.stack([zeros, np.full(len(x), k.fy), -dv], axis=1),
        ]
    )
    b = np.concatenate([du * x[:, 2] - k.fx * x[:, 0], dv * x[:, 2] - k.fy * x[:, 1]])
    # Each equation is a pixel error times the point's depth: dividing by a typical depth keeps
    # the rows comparable; the refinement below fixes what this algebraic error leaves.
    root_w = np.sqrt(np.concatenate([w, w]))
    t, *_ = np.linalg.lstsq(a * root_w[:, None], b * root_w, rcond=None)
    result: FloatArray = t
    return result


def _refine(
    x: FloatArray,
    u: FloatArray,
    w: FloatArray,
    k: Intrinsics,
    rotation: FloatArray,
    t: FloatArray,
    max_iterations: int,
    rotate: bool,
) -> Placement:
    """Levenberg-Marquardt on Σ w·|project(R·X + t) − u|², R updated as exp(δω)·R."""
    root_w = np.sqrt(w)
    scale = np.repeat(root_w[:, None], 2, axis=1).ravel()  # per residual, interleaved x, y

    def cost_of(rot: FloatArray, tr: FloatArray) -> tuple[float, FloatArray, FloatArray]:
        p = x @ rot.T + tr
        if (p[:, 2] <= MIN_DEPTH_M).any():
            return np.inf, p, np.zeros(0)
        inv_z = 1.0 / p[:, 2]
        r = np.empty(2 * len(p))
        r[0::2] = k.fx * p[:, 0] * inv_z + k.cx - u[:, 0]
        r[1::2] = k.fy * p[:, 1] * inv_z + k.cy - u[:, 1]
        r *= scale
        return float(r @ r), p, r

    cost, p, r = cost_of(rotation, t)
    if not np.isfinite(cost):
        raise PnPError("no placement in front of the camera (points at or behind it)")
    damping, steps = 1e-3, 0
    while steps < max_iterations:
        steps += 1
        jac = _jacobian(p, p - t, k, rotate) * scale[:, None]
        hessian, gradient = jac.T @ jac, jac.T @ r
        improved = False
        for _ in range(10):
            delta = np.linalg.solve(
                hessian + damping * np.diag(np.diag(hessian) + 1e-12), -gradient
            )
            if rotate:
                new_rotation = rotation_vector_to_matrix(delta[:3]) @ rotation
                new_t = t + delta[3:]
            else:
                new_rotation, new_t = rotation, t + delta
            new_cost, new_p, new_r = cost_of(new_rotation, new_t)
            if new_cost < cost:
                improved = True
                break
            damping *= 10.0
        if not improved:
            break
        # Converged: the cost fell by less than 1e-10 of itself, or the step is under 10 nm / rad.
        done = cost - new_cost <= 1e-10 * max(cost, 1e-12) or np.abs(delta).max() < 1e-8
        rotation, t, cost, p, r = new_rotation, new_t, new_cost, new_p, new_r
        damping = max(damping / 10.0, 1e-9)
        if done:
            break
    rms = float(np.sqrt(cost / w.sum()))
    return Placement(rotation, t, rms, steps)


def _jacobian(p: FloatArray, turned: FloatArray, k: Intrinsics, rotate: bool) -> FloatArray:
    """d(pixels)/d(δω, δt) (2N, 6), or d/dt (2N, 3), at camera-frame points p = R·X + t (N, 3);
    turned: R·X (N, 3). Rows interleave each point's x and y residuals."""
    inv_z = 1.0 / p[:, 2]
    ax, az = k.fx * inv_z, -k.fx * p[:, 0] * inv_z**2  # du/dp = (ax, 0, az)
    by, bz = k.fy * inv_z, -k.fy * p[:, 1] * inv_z**2  # dv/dp = (0, by, bz)
    n = len(p)
    jac = np.zeros((n, 2, 6 if rotate else 3))
    t0 = 3 if rotate else 0
    jac[:, 0, t0], jac[:, 0, t0 + 2] = ax, az
    jac[:, 1, t0 + 1], jac[:, 1, t0 + 2] = by, bz
    if rotate:
        # exp(δω)·R·X + t ≈ p + δω × q (q = R·X): d(point)/d(δω) = −[q]×, so
        # du/dδω = (az·q1, ax·q2 − az·q0, −ax·q1), dv/dδω = (−by·q2 + bz·q1, −bz·q0, by·q0).
        q0, q1, q2 = turned[:, 0], turned[:, 1], turned[:, 2]
        jac[:, 0, 0], jac[:, 0, 1], jac[:, 0, 2] = az * q1, ax * q2 - az * q0, -ax * q1
        jac[:, 1, 0], jac[:, 1, 1], jac[:, 1, 2] = bz * q1 - by * q2, -bz * q0, by * q0
    out: FloatArray = jac.reshape(2 * n, -1)
    return out


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
