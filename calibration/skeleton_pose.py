"""Relative pose of two sensors from the skeletons they both track (no equipment).

While one person walks through the capture area, both sensors report the same joints at the
same instants (the caller aligns them in time: the server interpolates each sensor's frames to
common instants). Each instant gives a few corresponding 3-D points; over many instants and
positions they pin down the rigid transform between the two sensor frames.

Why only a few joints. Kinect v2 skeletons are not the same body seen from two sides:

- **facing away**: a sensor behind the person reports a front-facing body with left and right
  swapped. Left/right joints then pair with the wrong side; midline joints do not care.
- **facing bias**: each tracker turns the skeleton towards its own sensor (about half the
  person's yaw relative to it, conventions.md §5), a rotation about the vertical through the
  pelvis. Points on that vertical axis do not move.

So the solver uses the midline joints SpineBase, SpineMid, SpineShoulder, Neck and Head and the
midpoints of the hips and of the shoulders (mirror-invariant by construction), all of which lie
near the pelvis' vertical axis; points higher up (neck, head) move a little when the trunk
leans, so they get lower weights. Only joints **Tracked** by both sensors are used (Inferred
joints are guesses). Then:

1. RANSAC over frames: a hypothesis is a Kabsch fit on the points of 3 frames at distinct
   positions; a frame is an inlier when the median residual of its points is under
   ``ransac_threshold_m``. The hypothesis with the most inlier points wins.
2. Iteratively reweighted refit on the inlier frames' points with Tukey's biweight, scale from
   the median absolute residual (floored at ``min_scale_m``); points beyond the biweight's
   cut-off are trimmed (glitches, mis-tracked frames).
3. A final weighted Kabsch on the kept points.

Trust (``SkeletonFit.trust``), from three measurements:

- residual: RMS distance of the kept points after the fit (Kinect v2 joints disagree by
  2–4 cm between views even when the pose is right);
- spread: how far the person walked: the smaller of the two largest standard deviations of the
  per-frame positions (a person standing still or walking on one line spreads little);
- frames: how many instants contributed.

``high``: residual ≤ 40 mm, spread ≥ 0.3 m, ≥ 150 frames (5 s at 30 fps), inlier ratio ≥ 0.6;
``medium``: residual ≤ 70 mm, spread ≥ 0.2 m, ≥ 60 frames, inlier ratio ≥ 0.4; otherwise
``low``. Even "high" means a few centimetres and about a degree or two, never ICP accuracy; the
facing bias of real trackers is not exactly a yaw about the pelvis, so this estimate is meant
as the initial guess for ICP on depth whenever depth is available.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import DegenerateGeometry, InvalidInput, NotEnoughCorrespondences
from skelfuse.calibration.rigid import RigidFit, fit_rigid, rotation_angle_deg
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState
from skelfuse.protocol.transform import Matrix4

J = JointId
FloatArray = npt.NDArray[np.float64]
Trust = Literal["low", "medium", "high"]

# (joint, joint, weight): a feature point is the midpoint of the two joints (the same joint
# twice for a midline joint). Weights fall with the height above the pelvis (lean sensitivity).
FEATURES: Final[tuple[tuple[int, int, float], ...]] = (
    (J.SPINE_BASE, J.SPINE_BASE, 1.0),
    (J.HIP_LEFT, J.HIP_RIGHT, 1.0),
    (J.SPINE_MID, J.SPINE_MID, 1.0),
    (J.SPINE_SHOULDER, J.SPINE_SHOULDER, 0.7),
    (J.SHOULDER_LEFT, J.SHOULDER_RIGHT, 0.7),
    (J.NECK, J.NECK, 0.5),
    (J.HEAD, J.HEAD, 0.5),
)
MIN_FRAMES: Final = 30
MIN_SPREAD_M: Final = 0.25
RGB_RANSAC_THRESHOLD_M: Final = 0.20
RGB_MIN_SCALE_M: Final = 0.05
"""``ransac_threshold_m`` and ``min_scale_m`` for pairs with an ``rgb`` (mono) sensor: its depth
rests on MediaPipe's guess of the body's size (4-9 % of the distance, per frame and as a bias),
so the Kinect's 10 cm / 15 mm keep too few frames and RANSAC can lock onto a wrong pose
(simulated 8 % depth noise and ±5 % size bias: 81° off with the defaults, 1.1° and 180 mm
with these; ``tests/unit/test_skeleton_mono.py``)."""


SKELETON_ERROR_BOUND: Final = (2.5, 75.0)
"""(degrees, millimetres) a skeleton estimate is rarely further off than (about twice the p95
measured by bench/calibration/methods.py): ICP refinements that move a skeleton estimate further are
refused (``refine_icp(max_correction=...)``)."""


@dataclass(frozen=True, slots=True)
class SkeletonFit:
    """Result of :func:`solve_from_skeletons`.

    ``T_ref_from_other``: (4, 4) float64, maps the other sensor's frame into the reference's.
    ``residual_mm``: RMS residual of the kept points. ``frames_used``: instants with at least
    one kept point. ``joints_used``: kept point pairs. ``inlier_ratio``: kept / usable points.
    ``spread_m``: how far the person moved (see module docstring). ``trust`` and ``warnings``:
    see the module docstring and docs/calibration.md.
    """

    T_ref_from_other: Matrix4
    residual_mm: float
    frames_used: int
    joints_used: int
    inlier_ratio: float
    trust: Trust
    warnings: list[str] = field(default_factory=list)
    spread_m: float = 0.0


def _check(
    joints: npt.ArrayLike, states: npt.ArrayLike, name: str
) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    j = np.asarray(joints, dtype=np.float64)
    s = np.asarray(states)
    if j.ndim != 3 or j.shape[1:] != (JOINT_COUNT, 3):
        raise InvalidInput(f"{name}_joints: expected shape (T, 25, 3), got {j.shape}")
    if s.shape != j.shape[:2]:
        raise InvalidInput(f"{name}_states: expected shape {j.shape[:2]}, got {s.shape}")
    if np.isinf(j).any():
        raise InvalidInput(f"{name}_joints contains inf; use NaN for missing joints")
    return j, s.astype(np.int64)


def _features(
    joints: FloatArray, states: npt.NDArray[np.int64]
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """(T, F, 3) feature points and (T, F) validity (both joints Tracked and finite)."""
    a = np.array([f[0] for f in FEATURES])
    b = np.array([f[1] for f in FEATURES])
    points = 0.5 * (joints[:, a] + joints[:, b])
    tracked = states == TrackingState.TRACKED
    valid = tracked[:, a] & tracked[:, b] & np.isfinite(points).all(axis=2)
    return points, valid


def _tukey(residual: FloatArray, scale: float) -> FloatArray:
    c = 4.685 * scale
    u = np.clip(residual / c, 0.0, 1.0)
    weights: FloatArray = (1.0 - u**2) ** 2
    return weights


def solve_from_skeletons(
    ref_joints: npt.ArrayLike,
    ref_states: npt.ArrayLike,
    other_joints: npt.ArrayLike,
    other_states: npt.ArrayLike,
    *,
    ransac_iterations: int = 300,
    ransac_threshold_m: float = 0.10,
    min_scale_m: float = 0.015,
    min_frames: int = MIN_FRAMES,
    min_spread_m: float = MIN_SPREAD_M,
    rng: np.random.Generator | None = None,
) -> SkeletonFit:
    """Fit ``T_ref_from_other`` from one person's skeletons seen by two sensors.

    Args:
        ref_joints: (T, 25, 3) joints in the reference sensor's frame (Kinect camera frame,
            metres), NaN where missing.
        ref_states: (T, 25) ``TrackingState`` values of the reference sensor.
        other_joints: (T, 25, 3) the same instants in the other sensor's frame.
        other_states: (T, 25).
        ransac_iterations: RANSAC hypotheses (3 frames each).
        ransac_threshold_m: a frame is an inlier when its median point residual is below this.
        min_scale_m: lower bound of the robust residual scale (Kinect joints are never better).
        min_frames: fewest instants with ≥ 2 usable points in both views.
        min_spread_m: smallest acceptable spread of the person's positions (see module doc).
        rng: random generator (default: seeded, reproducible).

    Returns:
        :class:`SkeletonFit`.

    Raises:
        InvalidInput: wrong shapes or inf.
        NotEnoughCorrespondences: fewer than ``min_frames`` usable instants.
        DegenerateGeometry: the person did not move enough to determine the pose.
    """
    ref_j, ref_s = _check(ref_joints, ref_states, "ref")
    oth_j, oth_s = _check(other_joints, other_states, "other")
    if ref_j.shape != oth_j.shape:
        raise InvalidInput(
            f"ref and other must cover the same instants: got {ref_j.shape[0]} and "
            f"{oth_j.shape[0]} frames; align both sensors to common instants first"
        )
    src, dst, base_w, frame_idx = _correspondences(ref_j, ref_s, oth_j, oth_s, min_frames)
    centroids, spread = _person_spread(dst, frame_idx, min_spread_m)
    generator = rng if rng is not None else np.random.default_rng(0)
    inlier_frames = _ransac_inlier_frames(
        src, dst, frame_idx, centroids, ransac_iterations, ransac_threshold_m, generator
    )
    final, kept = _robust_fit(src, dst, base_w, inlier_frames[frame_idx], min_scale_m)
    residual_mm = float(np.sqrt(np.mean(final.residuals_m[kept] ** 2))) * 1000.0
    frames_used = int(np.unique(frame_idx[kept]).size)
    joints_used = int(kept.sum())
    inlier_ratio = joints_used / len(src)
    trust, warnings = _trust(residual_mm, spread, frames_used, inlier_ratio)
    angle = rotation_angle_deg(final.T_dst_from_src)
    if angle > 90.0:
        warnings.append(
            f"the sensors are {angle:.0f}° apart: one of them sees the person's back much of "
            "the time; the midline joints cope with swapped sides, but refine with ICP"
        )
    return SkeletonFit(
        final.T_dst_from_src,
        residual_mm,
        frames_used,
        joints_used,
        inlier_ratio,
        trust,
        warnings,
        spread,
    )


def _correspondences(
    ref_j: FloatArray,
    ref_s: npt.NDArray[np.int64],
    oth_j: FloatArray,
    oth_s: npt.NDArray[np.int64],
    min_frames: int,
) -> tuple[FloatArray, FloatArray, FloatArray, npt.NDArray[np.intp]]:
    """The feature points valid in both views, at the instants with at least two of them.

    Returns:
        (P, 3) points in the other sensor's frame and (P, 3) the same in the reference's,
        metres; (P,) each point's feature weight; (P,) each point's frame number among the
        usable instants (0..U-1, points grouped by frame in order).

    Raises:
        NotEnoughCorrespondences: fewer than ``min_frames`` usable instants.
    """
    ref_f, ref_ok = _features(ref_j, ref_s)
    oth_f, oth_ok = _features(oth_j, oth_s)
    valid = ref_ok & oth_ok  # (T, F)
    frame_ok = valid.sum(axis=1) >= 2
    n_frames = int(frame_ok.sum())
    if n_frames < min_frames:
        raise NotEnoughCorrespondences(
            f"only {n_frames} instants where both sensors track the person's trunk (need "
            f"{min_frames}, of {ref_j.shape[0]} received); have one person walk where both "
            "sensors see them, facing each sensor part of the time, for 10-20 s"
        )
    frames = np.flatnonzero(frame_ok)
    frame_idx, feat_idx = np.nonzero(valid[frames])
    frame_of_point = frames[frame_idx]
    src = oth_f[frame_of_point, feat_idx]
    dst = ref_f[frame_of_point, feat_idx]
    base_w = np.array([f[2] for f in FEATURES])[feat_idx]
    return src, dst, base_w, frame_idx


def _person_spread(
    dst: FloatArray, frame_idx: npt.NDArray[np.intp], min_spread_m: float
) -> tuple[FloatArray, float]:
    """(U, 3) the person's position per usable frame (centroid of its points ``dst``, reference
    frame, metres) and their spread across the walking direction (second singular value, m).

    Raises:
        DegenerateGeometry: the positions spread less than ``min_spread_m`` along their longest
            direction.
    """
    n_frames = int(frame_idx.max()) + 1
    centroids = np.stack([dst[frame_idx == k].mean(axis=0) for k in range(n_frames)])
    spread_all = np.linalg.svd(centroids - centroids.mean(axis=0), compute_uv=False) / np.sqrt(
        len(centroids)
    )
    spread = float(spread_all[1]) if len(spread_all) > 1 else 0.0
    if float(spread_all[0]) < min_spread_m:
        raise DegenerateGeometry(
            f"the person hardly moved (positions spread over {spread_all[0] * 100:.0f} cm, need "
            f"{min_spread_m * 100:.0f} cm): walk around the whole capture area for 10-20 s "
            "while both sensors see you"
        )
    return centroids, spread


def _ransac_inlier_frames(
    src: FloatArray,
    dst: FloatArray,
    frame_idx: npt.NDArray[np.intp],
    centroids: FloatArray,
    iterations: int,
    threshold_m: float,
    generator: np.random.Generator,
) -> npt.NDArray[np.bool_]:
    """(U,) the frames that agree with the best of ``iterations`` three-frame hypotheses: its
    median point residual below ``threshold_m``; best = most points in agreeing frames.

    Raises:
        DegenerateGeometry: no hypothesis has any agreeing frame.
    """
    n_frames = len(centroids)
    best_score, best_inlier_frames = -1.0, np.zeros(n_frames, dtype=bool)
    counts = np.bincount(frame_idx, minlength=n_frames)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    median_col = (counts - 1) // 2  # lower median of each frame's residuals
    padded_rows = np.full((n_frames, len(FEATURES)), -1, dtype=np.int64)
    padded_rows[frame_idx, np.arange(len(frame_idx)) - starts[frame_idx]] = np.arange(len(src))
    for _ in range(iterations):
        pick = generator.choice(n_frames, size=3, replace=False)
        c = centroids[pick]
        if min(np.linalg.norm(c[0] - c[1]), np.linalg.norm(c[0] - c[2]),
               np.linalg.norm(c[1] - c[2])) < 0.2:  # fmt: skip
            continue
        rows = padded_rows[pick].reshape(-1)
        rows = rows[rows >= 0]
        try:
            hypothesis = fit_rigid(src[rows], dst[rows], min_spread_m=0.02)
        except DegenerateGeometry:
            continue
        t = hypothesis.T_dst_from_src
        residual = np.linalg.norm(src @ t[:3, :3].T + t[:3, 3] - dst, axis=1)
        per_frame = np.sort(np.where(padded_rows >= 0, residual[padded_rows], np.inf), axis=1)[
            np.arange(n_frames), median_col
        ]
        inlier_frames = per_frame < threshold_m
        score = float(counts[inlier_frames].sum())
        if score > best_score:
            best_score, best_inlier_frames = score, inlier_frames
    if best_score <= 0:
        raise DegenerateGeometry(
            "no consistent pose found: the two sensors' skeletons never agree; check that both "
            "sensors track the same single person at the same instants"
        )
    return best_inlier_frames


def _robust_fit(
    src: FloatArray,
    dst: FloatArray,
    base_w: FloatArray,
    keep: npt.NDArray[np.bool_],
    min_scale_m: float,
) -> tuple[RigidFit, npt.NDArray[np.bool_]]:
    """Weighted rigid fit of the ``keep`` points, reweighted ten times by Tukey's biweight of
    the residuals (scale: 1.4826 · median, at least ``min_scale_m``), then refitted on the
    points with weight left. Returns that fit and the (P,) points it used."""
    weights = base_w * keep
    fit = fit_rigid(src, dst, weights, min_spread_m=0.02)
    for _ in range(10):
        r = fit.residuals_m
        scale = max(float(1.4826 * np.median(r[weights > 0])), min_scale_m)
        weights = base_w * keep * _tukey(r, scale)
        fit = fit_rigid(src, dst, weights, min_spread_m=0.02)
    kept = weights > 0
    return fit_rigid(src, dst, base_w * kept, min_spread_m=0.02), kept


def _trust(
    residual_mm: float, spread_m: float, frames: int, inlier_ratio: float
) -> tuple[Trust, list[str]]:
    warnings: list[str] = []
    if residual_mm > 70:
        warnings.append(
            f"large residual ({residual_mm:.0f} mm): the skeletons disagree more than usual "
            "(several people, wrong time alignment, or a sensor that mostly sees the back)"
        )
    if spread_m < 0.2:
        warnings.append(
            f"small spread ({spread_m * 100:.0f} cm across the walking direction): walk a loop "
            "around the whole capture area, not a straight line"
        )
    if frames < 60:
        warnings.append(f"only {frames} frames used: record for longer (10-20 s)")
    if inlier_ratio < 0.4:
        warnings.append(
            f"only {inlier_ratio:.0%} of the joint pairs agree with the fit: tracking was poor"
        )
    if residual_mm <= 40 and spread_m >= 0.3 and frames >= 150 and inlier_ratio >= 0.6:
        return "high", warnings
    if residual_mm <= 70 and spread_m >= 0.2 and frames >= 60 and inlier_ratio >= 0.4:
        return "medium", warnings
    return "low", warnings
