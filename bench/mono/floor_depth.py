"""Depth from the floor against PnP's depth, per camera of the real clip (issue 14 item 2).

    .venv/bin/python -m bench floor_depth

Inputs: ``tests/data/mono_landmarks.npz`` (MediaPipe on the four videos) and the clip's
Qualisys calibration ``tests/data/pose2sim_single_calib.qca.txt``. The reference is the
landmarks triangulated from all four views (:func:`calibration.triangulation.triangulate`,
views beyond 20 px dropped), with cam03's clock lag from the motion
(:func:`calibration.motion_sync.lags_from_epipolar`, rounded to whole frames); each camera is
compared at its own frames with the reference at the same instant. Consistency, not truth.

Each camera alone places every frame as ``skelfuse mocap`` does (:func:`recording.video_take.
place_video`: undistortion, PnP rotation + translation from the previous frame), then:

- ``pnp``: PnP's distance (the body's size as MediaPipe guesses it);
- ``floor``: the product's default, scaled about the camera centre until the lowest foot point
  stands 3 cm above the floor, running median over 9 frames (0.15 s);
- ``floor, no median``: the same, frame by frame;
- ``blend``: the mean of the two distances (scale (1 + s) / 2).

Then the feet hidden (visibility 0) for 40 frames mid-clip: PnP's distance in those frames, or
the floor's scale carried across them from the frames around (the product's default).

Errors on MediaPipe's twelve limb landmarks (shoulders, elbows, wrists, hips, knees, ankles),
in mm: absolute (mean and median), root-aligned (mean; root = mid-hip: the body's shape and
size once its position is forgiven), and the root's own position error (median). Pure
geometry: the load does not change the figures.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.camera import SENSOR_FROM_OPENCV, Camera
from skelfuse.calibration.camera_files import read_camera_file
from skelfuse.calibration.floor_depth import FloorDepthSettings
from skelfuse.calibration.motion_sync import lags_from_epipolar
from skelfuse.calibration.triangulation import triangulate
from skelfuse.recording.video_take import (
    CameraTrack,
    MocapSettings,
    VideoLandmarks,
    place_video,
    read_landmarks,
)

ROOT = Path(__file__).resolve().parents[2]

FloatArray = npt.NDArray[np.float64]
DATA = ROOT / "tests" / "data"
CAMERAS = ("cam01", "cam02", "cam03", "cam04")
RATE_HZ = 60.0
LIMBS = (11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)
HIPS = (6, 7)  # positions of the hips in LIMBS
METHODS = ("pnp", "floor", "floor, no median", "blend")
HIDDEN = slice(30, 70)
"""Frames whose feet :func:`hidden_feet` hides (0.67 s mid-clip)."""


def reference(
    videos: list[VideoLandmarks], cameras: dict[str, Camera]
) -> tuple[FloatArray, dict[str, int]]:
    """(T, 33, 3) world landmarks from all views in the first camera's time, and each camera's
    lag in whole frames (its frame s shows the reference's instant s - lag)."""
    cams = [cameras[v.name] for v in videos]
    pixels = np.stack([v.image_px[..., :2] for v in videos])
    weights = np.stack([v.visibility for v in videos])
    sync = lags_from_epipolar(cams, pixels, weights, rate_hz=RATE_HZ)
    lags = {name: round(lag) for name, lag in sync.lag_frames.items()}
    frames = pixels.shape[1]
    aligned = np.full_like(pixels, np.nan)
    aligned_w = np.zeros_like(weights)
    for k, video in enumerate(videos):
        lag = lags[video.name]
        src = slice(max(lag, 0), frames + min(lag, 0))
        dst = slice(max(-lag, 0), frames - max(lag, 0))
        aligned[k, dst], aligned_w[k, dst] = pixels[k, src], weights[k, src]
    points = triangulate(cams, aligned, aligned_w, max_error_px=20.0).points_world
    return points, lags


def world(track: CameraTrack, camera: Camera) -> FloatArray:
    T = camera.T_world_from_sensor @ SENSOR_FROM_OPENCV
    out: FloatArray = track.landmarks_cv @ T[:3, :3].T + T[:3, 3]
    return out


def errors_mm(pred: FloatArray, ref: FloatArray) -> dict[str, float]:
    """Absolute mean/median, root-aligned mean, root median, over frames where both exist."""
    p, r = pred[:, LIMBS], ref[:, LIMBS]
    ok = np.isfinite(p).all(axis=(1, 2)) & np.isfinite(r).all(axis=(1, 2))
    p, r = p[ok], r[ok]
    absolute = np.linalg.norm(p - r, axis=-1) * 1000
    root_p, root_r = p[:, HIPS].mean(axis=1), r[:, HIPS].mean(axis=1)
    aligned = np.linalg.norm((p - root_p[:, None]) - (r - root_r[:, None]), axis=-1) * 1000
    return {
        "abs_mean": float(absolute.mean()),
        "abs_median": float(np.median(absolute)),
        "root_aligned": float(aligned.mean()),
        "root": float(np.median(np.linalg.norm(root_p - root_r, axis=-1)) * 1000),
    }


def variants(
    video: VideoLandmarks, camera: Camera, methods: tuple[str, ...] = METHODS
) -> dict[str, FloatArray]:
    """World landmarks of one camera by each way of setting its distance (``methods``)."""
    pnp = place_video(video, camera, settings=MocapSettings(floor=None))
    floor = place_video(video, camera)
    out = {"pnp": world(pnp, camera), "floor": world(floor, camera)}
    if "floor, no median" in methods:
        single = MocapSettings(floor=FloorDepthSettings(window_frames=1))
        out["floor, no median"] = world(place_video(video, camera, settings=single), camera)
    if "blend" in methods:
        halfway = ((1 + floor.floor_scales) / 2)[:, None, None]
        out["blend"] = world(replace(pnp, landmarks_cv=pnp.landmarks_cv * halfway), camera)
    return {method: out[method] for method in methods}


def hidden_feet(
    video: VideoLandmarks, camera: Camera, truth: FloatArray, gap: slice = HIDDEN
) -> dict[str, float]:
    """Absolute mean error (mm) over ``gap`` with the feet's visibility set to 0 there: PnP,
    the floor with PnP's distance in the gap, the floor carried across it (the default)."""
    visibility = video.visibility.copy()
    visibility[gap, 29:33] = 0.0
    hidden = replace(video, visibility=visibility)
    out = {}
    for method, floor in (
        ("pnp", None),
        ("floor, pnp in the gap", FloorDepthSettings(fill="pnp")),
        ("floor, carried across", FloorDepthSettings()),
    ):
        track = place_video(hidden, camera, settings=MocapSettings(floor=floor))
        out[method] = errors_mm(world(track, camera)[gap], truth[gap])["abs_mean"]
    return out


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)  # --help
    videos = read_landmarks(DATA / "mono_landmarks.npz", CAMERAS)
    found = read_camera_file(DATA / "pose2sim_single_calib.qca.txt", "qualisys")
    cameras = {c.name: c for c in found.cameras}
    ref, lags = reference(videos, cameras)
    print(f"lags (frames, rounded): {lags}")
    print("| camera | method | abs mean | abs median | root-aligned | root |")
    print("|---|---|---:|---:|---:|---:|")
    totals: dict[str, list[float]] = {}
    gaps: list[dict[str, float]] = []
    for video in videos:
        lag = lags[video.name]
        # camera frame s shows the reference's instant s - lag
        shifted = np.full_like(ref, np.nan)
        frames = ref.shape[0]
        src = slice(max(-lag, 0), frames - max(lag, 0))
        dst = slice(max(lag, 0), frames + min(lag, 0))
        shifted[dst] = ref[src]
        for method, pred in variants(video, cameras[video.name]).items():
            e = errors_mm(pred, shifted)
            totals.setdefault(method, []).append(e["abs_mean"])
            print(f"| {video.name} | {method} | {e['abs_mean']:.0f} | {e['abs_median']:.0f} | "
                  f"{e['root_aligned']:.0f} | {e['root']:.0f} |")  # fmt: skip
        gaps.append(hidden_feet(video, cameras[video.name], shifted))
    print()
    for method, values in totals.items():
        print(f"{method}: mean over cameras of the absolute mean {np.mean(values):.0f} mm")
    print(f"\nfeet hidden in frames {HIDDEN.start}-{HIDDEN.stop - 1}: absolute mean there, mm")
    for method in gaps[0]:
        row = " | ".join(f"{gap[method]:.0f}" for gap in gaps)
        print(f"{method}: {row} (mean {np.mean([gap[method] for gap in gaps]):.0f})")
