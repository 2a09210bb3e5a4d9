"""The mono accuracy benchmark's metrics: MPJPE (absolute, root-aligned, Procrustes-aligned),
2-D pixel error and PCK at a fraction of the torso size, and time shifts of landmark tracks.

Joints compared: MediaPipe's twelve limb landmarks (:data:`LIMB_LANDMARKS`), the joints every
view and the 25-joint model have in common: shoulders, elbows, wrists, hips, knees, ankles.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JointId

FloatArray = npt.NDArray[np.float64]

LIMB_LANDMARKS: Final = (11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)
"""MediaPipe Pose indices: shoulder, elbow, wrist (left, right), hip, knee, ankle (left, right)."""
LIMB_JOINTS: Final = (
    JointId.SHOULDER_LEFT, JointId.SHOULDER_RIGHT, JointId.ELBOW_LEFT, JointId.ELBOW_RIGHT,
    JointId.WRIST_LEFT, JointId.WRIST_RIGHT, JointId.HIP_LEFT, JointId.HIP_RIGHT,
    JointId.KNEE_LEFT, JointId.KNEE_RIGHT, JointId.ANKLE_LEFT, JointId.ANKLE_RIGHT,
)  # fmt: skip
"""The 25-joint model's joints of :data:`LIMB_LANDMARKS`, in the same order."""
HIPS: Final = (6, 7)
"""Positions of the two hips in :data:`LIMB_LANDMARKS`: their midpoint is the root."""
SHOULDERS: Final = (0, 1)


def mpjpe(pred: FloatArray, ref: FloatArray) -> FloatArray:
    """Per (frame, joint) distance, same unit as the inputs: pred, ref (T, J, 3) → (T, J)."""
    return np.asarray(np.linalg.norm(pred - ref, axis=-1), dtype=np.float64)


def root_aligned(pred: FloatArray, ref: FloatArray) -> FloatArray:
    """Distances after moving each frame's prediction so its root (mid-hip) meets the
    reference's: (T, J, 3) twice → (T, J)."""
    root_p = pred[:, HIPS, :].mean(axis=1, keepdims=True)
    root_r = ref[:, HIPS, :].mean(axis=1, keepdims=True)
    return mpjpe(pred - root_p, ref - root_r)


def procrustes_aligned(pred: FloatArray, ref: FloatArray) -> FloatArray:
    """Distances after the best similarity (rotation, uniform scale, translation) per frame
    (Umeyama's least squares; reflections excluded): (T, J, 3) twice → (T, J).

    Joints missing (NaN) in either are left out of the fit and come back NaN.
    """
    out = np.full(pred.shape[:2], np.nan)
    for i, (p, r) in enumerate(zip(pred, ref, strict=True)):
        ok = np.isfinite(p).all(axis=1) & np.isfinite(r).all(axis=1)
        if ok.sum() < 3:
            continue
        mu_p, mu_r = p[ok].mean(axis=0), r[ok].mean(axis=0)
        pc, rc = p[ok] - mu_p, r[ok] - mu_r
        u, s, vt = np.linalg.svd(rc.T @ pc)
        d = np.sign(np.linalg.det(u @ vt))
        fix = np.diag([1.0, 1.0, d])
        rot = u @ fix @ vt
        scale = float((s * np.diag(fix)).sum() / (pc**2).sum())
        aligned = scale * (p - mu_p) @ rot.T + mu_r
        out[i] = np.linalg.norm(aligned - r, axis=-1)
    return out


def torso_px(landmarks_px: FloatArray) -> FloatArray:
    """Torso size per frame, pixels: mid-shoulder to mid-hip of (T, J, 2) limb landmarks → (T,)."""
    shoulders = landmarks_px[:, SHOULDERS, :].mean(axis=1)
    hips = landmarks_px[:, HIPS, :].mean(axis=1)
    return np.asarray(np.linalg.norm(shoulders - hips, axis=-1), dtype=np.float64)


def pixel_errors(pred_px: FloatArray, ref_px: FloatArray) -> FloatArray:
    """Per (frame, joint) pixel distance: (T, J, 2) twice → (T, J) (NaN where either is)."""
    return np.asarray(np.linalg.norm(pred_px - ref_px, axis=-1), dtype=np.float64)


def pck(errors_px: FloatArray, torso: FloatArray, fraction: float = 0.2) -> float:
    """Share of finite (frame, joint) errors within ``fraction`` × that frame's torso size.

    Raises:
        ValueError: no finite error to judge.
    """
    ok = np.isfinite(errors_px) & np.isfinite(torso)[:, None]
    if not ok.any():
        raise ValueError("no finite errors")
    within = errors_px <= fraction * torso[:, None]
    return float(within[ok].mean())


def median(errors: FloatArray) -> float:
    """Median of the finite values (NaN if none)."""
    finite = errors[np.isfinite(errors)]
    return float(np.median(finite)) if finite.size else float("nan")


def sample(track: FloatArray, positions: FloatArray) -> FloatArray:
    """``track`` (T, ...) at fractional frame ``positions`` (N,), linear between frames; NaN
    outside [0, T − 1] → (N, ...)."""
    n = track.shape[0]
    pos = np.asarray(positions, dtype=np.float64)
    lo = np.clip(np.floor(pos).astype(int), 0, max(n - 2, 0))
    frac = (pos - lo).reshape((-1,) + (1,) * (track.ndim - 1))
    out = (1 - frac) * track[lo] + frac * track[np.minimum(lo + 1, n - 1)]
    out[(pos < 0) | (pos > n - 1)] = np.nan
    return np.asarray(out, dtype=np.float64)


def shifted(track: FloatArray, shift_frames: float) -> FloatArray:
    """``track`` (T, ...) sampled at frame i + ``shift_frames`` (:func:`sample`): a camera
    lagging by L frames is aligned with the others by ``shifted(track, L)``."""
    return sample(track, np.arange(track.shape[0], dtype=np.float64) + shift_frames)
