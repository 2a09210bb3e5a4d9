"""Single camera against the four-view reference (issue 14, "Tests and figures").

The reference: MediaPipe's image landmarks of all four cameras triangulated (visibility-weighted
DLT, :func:`bench.mono_accuracy_geometry.triangulate`), cam03 shifted by its lag first. A single
camera: its world landmarks (metres, hip-centred, camera-like axes) placed in its camera frame by
PnP against its own image landmarks, then moved into the room by its extrinsics. Compared on the
twelve limb landmarks (:data:`bench.mono_accuracy_metrics.LIMB_LANDMARKS`): MPJPE absolute,
root-aligned and Procrustes-aligned (targets: root-aligned ≤ 150 mm, Procrustes ≤ 80 mm).

The reference is consistency, not truth (the clip has no markers): it shares MediaPipe's biases
with the single cameras, so these figures are lower bounds of the real error.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from bench.mono_accuracy_geometry import Camera, FloatArray, pnp, project, triangulate
from bench.mono_accuracy_metrics import (
    LIMB_LANDMARKS,
    median,
    mpjpe,
    procrustes_aligned,
    root_aligned,
    shifted,
)

ROOT = Path(__file__).resolve().parents[1]
FIXTURE: Final = ROOT / "tests" / "data" / "mono_landmarks.npz"
CALIBRATION: Final = ROOT.parent / "shared" / "data" / "pose2sim-single" / "Calib.qca.txt"
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
    vis = np.stack([clip.visibility[c] for c in names])
    v, t, j, _ = px.shape
    points = triangulate(
        px.reshape(v, t * j, 2), vis.reshape(v, t * j), [cameras[c] for c in names]
    )
    return points.reshape(t, j, 3)


def reprojection_px(points: FloatArray, clip: Clip, cameras: dict[str, Camera]) -> float:
    """Median pixel distance between ``points`` (T, 33, 3) projected into every camera and
    that camera's landmarks, over the limb landmarks."""
    limbs = list(LIMB_LANDMARKS)
    errors = [
        np.linalg.norm(project(points[:, limbs], cam) - clip.image_px[c][:, limbs], axis=-1)
        for c, cam in cameras.items()
    ]
    return median(np.concatenate([e.ravel() for e in errors]))


def lag_by_reprojection(
    clip: Clip, cameras: dict[str, Camera], camera: str, candidates: FloatArray
) -> float:
    """The shift of ``camera`` (frames) that makes the four views agree best (lowest median
    reprojection error of their triangulation): a cross-check of the motion sync, which
    needs no calibration."""
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
    """One camera's landmarks in its OpenCV camera frame (T, 33, 3) metres: per frame, PnP of
    its world landmarks against its image landmarks (all 33)."""
    out = np.full(clip.world_m[name].shape, np.nan)
    for i, (px, local) in enumerate(zip(clip.image_px[name], clip.world_m[name], strict=True)):
        if not np.isfinite(local).all():
            continue
        R, t = pnp(px, local, cam)
        out[i] = local @ R.T + t
    return out


def single_camera(clip: Clip, cam: Camera, name: str) -> FloatArray:
    """One camera's landmarks in the room (T, 33, 3): :func:`in_camera`, then its extrinsics."""
    return (in_camera(clip, cam, name) - cam.t) @ cam.R  # R^T (p - t), row vectors


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
