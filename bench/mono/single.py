"""Single camera against the four-view reference (issue 14, "Tests and figures").

The reference: MediaPipe's image landmarks of all four cameras triangulated (visibility-weighted
DLT, :func:`skelfuse.calibration.triangulation.triangulate`), cam03 shifted by its lag first. A
single camera: its world landmarks (metres, hip-centred, camera axes) placed in its camera frame
by the ``mono`` source's PnP (:func:`skelfuse.protocol.mediapipe_pose.place_landmarks`, rotation
and translation, each frame starting from the last), then moved into the room by its extrinsics.
Compared on the
twelve limb landmarks (:data:`bench.mono.metrics.LIMB_LANDMARKS`): MPJPE absolute,
root-aligned and Procrustes-aligned (targets: root-aligned ≤ 150 mm, Procrustes ≤ 80 mm).

The reference is consistency, not truth (the clip has no markers): it shares MediaPipe's biases
with the single cameras, so these figures are lower bounds of the real error.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from bench.mono.geometry import FloatArray, opencv_to_world, pinhole, undistorted_px
from bench.mono.metrics import (
    LIMB_LANDMARKS,
    median,
    mpjpe,
    procrustes_aligned,
    root_aligned,
    shifted,
)
from skelfuse.calibration.camera import Camera
from skelfuse.calibration.motion_sync import lags_from_epipolar
from skelfuse.calibration.triangulation import triangulate
from skelfuse.geometry.pnp import Placement
from skelfuse.protocol.mediapipe_pose import place_landmarks

ROOT = Path(__file__).resolve().parents[2]
FIXTURE: Final = ROOT / "tests" / "data" / "mono_landmarks.npz"
CALIBRATION: Final = ROOT / "tests" / "data" / "pose2sim_single_calib.qca.txt"
"""The clip's Qualisys calibration (a copy of ``../shared/data/pose2sim-single/Calib.qca.txt``)."""
CAMERAS: Final = ("cam01", "cam02", "cam03", "cam04")
FPS: Final = 60.0


@dataclass(frozen=True)
class Clip:
    """The fixture's landmarks per camera: image (T, 33, 2) px, world (T, 33, 3) m, visibility
    (T, 33); frames where MediaPipe found nobody are NaN."""

    image_px: dict[str, FloatArray]
    world_m: dict[str, FloatArray]
    visibility: dict[str, FloatArray]

    def shifted(self, lags: dict[str, float]) -> Clip:
        """Each camera's tracks resampled at frame i + its lag (cameras not named stay)."""

        def move(tracks: dict[str, FloatArray]) -> dict[str, FloatArray]:
            return {
                c: shifted(a, lags.get(c, 0.0)) if lags.get(c) else a for c, a in tracks.items()
            }

        return Clip(move(self.image_px), move(self.world_m), move(self.visibility))


def load_clip(path: Path = FIXTURE) -> Clip:
    """The landmark fixture (keys ``<cam>_image_px``, ``_world_m``, ``_visibility``,
    ``_detected``).

    Raises:
        OSError, KeyError: the file is missing or lacks a camera's keys.
    """
    with np.load(path) as data:
        image, world, vis = {}, {}, {}
        for cam in CAMERAS:
            seen = data[f"{cam}_detected"].astype(bool)
            image[cam] = np.where(seen[:, None, None], data[f"{cam}_image_px"][..., :2], np.nan)
            world[cam] = np.where(seen[:, None, None], data[f"{cam}_world_m"], np.nan)
            vis[cam] = np.where(seen[:, None], data[f"{cam}_visibility"], 0.0)
    return Clip(image, world, vis)


def reference(
    clip: Clip, cameras: dict[str, Camera], names: tuple[str, ...] = CAMERAS
) -> FloatArray:
    """Triangulated landmarks (T, 33, 3), world metres, from the named cameras' views."""
    px = np.stack([clip.image_px[c] for c in names])  # (V, T, 33, 2)
    vis = np.nan_to_num(np.stack([clip.visibility[c] for c in names]))  # NaN: shifted off the clip
    return triangulate([cameras[c] for c in names], px, vis).points_world


def motion_sync_lags(clip: Clip, cameras: dict[str, Camera]) -> dict[str, float]:
    """Each camera's lag behind cam01 (frames) from the product's motion sync
    (:func:`skelfuse.calibration.motion_sync.lags_from_epipolar`), visibility as weights."""
    px = np.stack([clip.image_px[c] for c in CAMERAS])
    vis = np.nan_to_num(np.stack([clip.visibility[c] for c in CAMERAS]))
    sync = lags_from_epipolar([cameras[c] for c in CAMERAS], px, vis, rate_hz=FPS)
    return dict(sync.lag_frames)


def reprojection_px(points: FloatArray, clip: Clip, cameras: dict[str, Camera]) -> float:
    """Median pixel distance between ``points`` (T, 33, 3) projected into every camera and
    that camera's landmarks, over the limb landmarks."""
    limbs = list(LIMB_LANDMARKS)
    errors = [
        np.linalg.norm(cam.project(points[:, limbs]) - clip.image_px[c][:, limbs], axis=-1)
        for c, cam in cameras.items()
    ]
    return median(np.concatenate([e.ravel() for e in errors]))


def lag_by_reprojection(
    clip: Clip, cameras: dict[str, Camera], camera: str, candidates: FloatArray
) -> float:
    """The shift of ``camera`` (frames) that makes the four views agree best (lowest median
    reprojection error of their triangulation): a cross-check of the motion sync by another
    criterion than its epipolar distance."""
    scores = [
        reprojection_px(
            reference(clip.shifted({camera: float(s)}), cameras),
            clip.shifted({camera: float(s)}),
            cameras,
        )
        for s in candidates
    ]
    return float(candidates[int(np.argmin(scores))])


def in_camera(clip: Clip, cam: Camera, name: str) -> FloatArray:
    """One camera's landmarks in its OpenCV camera frame (T, 33, 3) metres: per frame, the
    ``mono`` source's PnP of its world landmarks against its (undistorted) image landmarks."""
    out = np.full(clip.world_m[name].shape, np.nan)
    intrinsics = pinhole(cam)
    last: Placement | None = None
    for i, (px, local, vis) in enumerate(
        zip(clip.image_px[name], clip.world_m[name], clip.visibility[name], strict=True)
    ):
        if not np.isfinite(local).all():
            continue
        out[i], last = place_landmarks(
            undistorted_px(cam, px), local, vis, intrinsics, initial=last
        )
    return out


def single_camera(clip: Clip, cam: Camera, name: str) -> FloatArray:
    """One camera's landmarks in the room (T, 33, 3): :func:`in_camera`, then its extrinsics."""
    return opencv_to_world(cam, in_camera(clip, cam, name))


def single_vs_reference(
    clip: Clip, cameras: dict[str, Camera], ref: FloatArray
) -> dict[str, dict[str, float]]:
    """Per camera: mean and median of the three MPJPEs (mm) on the limb landmarks, against
    ``ref`` (T, 33, 3)."""
    limbs = list(LIMB_LANDMARKS)
    rows: dict[str, dict[str, float]] = {}
    for name, cam in cameras.items():
        pred = single_camera(clip, cam, name)[:, limbs]
        r = ref[:, limbs]
        ok = np.isfinite(pred).all(axis=(1, 2)) & np.isfinite(r).all(axis=(1, 2))
        row: dict[str, float] = {"frames": float(ok.sum())}
        for label, fn in (
            ("abs", mpjpe),
            ("root", root_aligned),
            ("procrustes", procrustes_aligned),
        ):
            errors = 1000.0 * fn(pred[ok], r[ok])
            row[f"{label}_mean"] = float(np.mean(errors))
            row[f"{label}_median"] = median(errors)
        rows[name] = row
    return rows
