"""The ``mono`` source's CPU per frame on the real clip, and numpy PnP against OpenCV's.

Runs in the mono environment (``scripts/venv_mono.sh`` makes ``.venv-mono``; mediapipe 0.10.21
pins numpy<2)::

    .venv-mono/bin/python -m bench mono_source [--data ../shared/data/pose2sim-single] [--json F]

Per camera of the clip (four portrait 1080×1920 videos, 100 frames each):

- **detect**: process CPU per frame of MediaPipe Pose (``PoseDetector.detect``, video mode,
  ``model_complexity=1``), the model loaded before timing; the target is <= 60 ms (issue 14);
- **map**: process CPU per frame of :func:`skelfuse.protocol.mediapipe_pose.body_from_landmarks`
  (numpy PnP, full pose, warm-started from the previous frame, plus the 25-joint mapping);
- **numpy vs cv2**: on the same landmarks, unweighted, ``solve_pose`` against
  ``cv2.solvePnP(SOLVEPNP_ITERATIVE)``: the frames where both reach the same minimum (translation
  within 1 mm), the largest difference there, and the frames where one of them lands in a worse
  minimum (higher reprojection error than the other's, or behind the camera: OpenCV starts from
  a DLT and sometimes ends 180° turned behind the camera with a lower error, as the projection
  of points with negative depth allows; ours starts from the translation-only fit with R = I
  and refuses depths <= 5 cm), with both solvers' median time.

Frames are decoded before timing (decoding is not the source's cost to judge). Medians over
frames; figures are process CPU, so they are comparable at a load average near 1 only: the
load average is printed with them.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.agent.sources.mono_camera import Landmarks, PoseDetector, VideoFrames
from skelfuse.geometry.pinhole import Intrinsics
from skelfuse.geometry.pnp import Placement, solve_pose
from skelfuse.protocol.mediapipe_pose import body_from_landmarks

ROOT = Path(__file__).resolve().parents[2]
CAMERAS = ("cam01", "cam02", "cam03", "cam04")
FOV_DEG = 50.0  # only the scale of the placements depends on it, not the timings


def _frames(video: Path) -> list[np.ndarray]:
    reader = VideoFrames(video)
    frames = []
    while (image := reader.read()) is not None:
        frames.append(image)
    reader.close()
    return frames


def _cv2_pose(cv2: Any, world: np.ndarray, pixels: np.ndarray, k: Intrinsics) -> tuple:  # type: ignore[type-arg]
    started = time.process_time()
    _, rvec, tvec = cv2.solvePnP(world, pixels, k.matrix(), None, flags=cv2.SOLVEPNP_ITERATIVE)
    spent = time.process_time() - started
    projected, _ = cv2.projectPoints(world, rvec, tvec, k.matrix(), None)
    rms = float(np.sqrt(((projected[:, 0] - pixels) ** 2).sum(axis=1).mean()))
    return np.asarray(tvec, dtype=np.float64).ravel(), rms, spent


def bench_camera(video: Path, cv2: Any) -> dict[str, Any]:
    """The figures of one video."""
    frames = _frames(video)
    height, width = frames[0].shape[:2]
    k = Intrinsics.from_fov(width, height, FOV_DEG)
    detector = PoseDetector()
    detect_ms, map_ms, found = [], [], []
    previous: Placement | None = None
    for image in frames:
        started = time.process_time()
        marks = detector.detect(image)
        detect_ms.append((time.process_time() - started) * 1000)
        if marks is None:
            previous = None
            continue
        found.append(marks)
        started = time.process_time()
        body = body_from_landmarks(
            marks.image_px, marks.world_m, marks.visibility, (width, height), k, initial=previous
        )
        map_ms.append((time.process_time() - started) * 1000)
        previous = body.placement
    detector.close()
    return {
        "frames": len(frames),
        "detected": len(found),
        "detect_ms_median": statistics.median(detect_ms),
        "detect_ms_p90": float(np.percentile(detect_ms, 90)),
        "map_ms_median": statistics.median(map_ms) if map_ms else None,
        **_compare_pnp(found, k, cv2),
    }


def _compare_pnp(found: list[Landmarks], k: Intrinsics, cv2: Any) -> dict[str, Any]:
    same, worse_cv2, worse_ours, diffs_mm, ours_ms, theirs_ms = 0, 0, 0, [], [], []
    for marks in found:
        world = marks.world_m.astype(np.float64)
        pixels = marks.image_px[:, :2].astype(np.float64)
        started = time.process_time()
        ours = solve_pose(world, pixels, k)
        ours_ms.append((time.process_time() - started) * 1000)
        t_cv2, rms_cv2, spent = _cv2_pose(cv2, world, pixels, k)
        theirs_ms.append(spent * 1000)
        diff_mm = float(np.linalg.norm(ours.translation - t_cv2)) * 1000
        if diff_mm < 1.0:
            same += 1
            diffs_mm.append(diff_mm)
        elif rms_cv2 > ours.rms_px or t_cv2[2] <= 0:  # behind the camera: not a placement
            worse_cv2 += 1
        else:
            worse_ours += 1
    return {
        "pnp_same_minimum": same,
        "pnp_same_max_diff_mm": max(diffs_mm) if diffs_mm else None,
        "pnp_cv2_worse_minimum": worse_cv2,
        "pnp_numpy_worse_minimum": worse_ours,
        "pnp_numpy_ms_median": statistics.median(ours_ms) if ours_ms else None,
        "pnp_cv2_ms_median": statistics.median(theirs_ms) if theirs_ms else None,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared/data/pose2sim-single")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)
    cv2 = importlib.import_module("cv2")
    load_before = os.getloadavg()[0]
    results = {camera: bench_camera(args.data / f"{camera}.mp4", cv2) for camera in CAMERAS}
    load_after = os.getloadavg()[0]
    for camera, r in results.items():
        print(
            f"{camera}: {r['detected']}/{r['frames']} detected; CPU/frame detect "
            f"{r['detect_ms_median']:.1f} ms (p90 {r['detect_ms_p90']:.1f}), map "
            f"{r['map_ms_median']:.2f} ms; PnP numpy = cv2 on {r['pnp_same_minimum']} frames "
            f"(max {r['pnp_same_max_diff_mm']:.4f} mm), cv2 in a worse minimum on "
            f"{r['pnp_cv2_worse_minimum']}, ours on {r['pnp_numpy_worse_minimum']}; "
            f"PnP {r['pnp_numpy_ms_median']:.2f} ms numpy, "
            f"{r['pnp_cv2_ms_median']:.2f} ms cv2"
        )
    print(f"load average {load_before:.2f} before, {load_after:.2f} after")
    if args.json is not None:
        payload = {"load_average": [load_before, load_after], "cameras": results}
        args.json.write_text(json.dumps(payload, indent=2))
