"""Regenerate ``tests/data/mono_landmarks.npz``: MediaPipe Pose landmarks of the real clip.

Run in the mono environment (``scripts/venv_mono.sh`` makes ``.venv-mono``; mediapipe 0.10.21
pins numpy<2, so it cannot live in the main one)::

    .venv-mono/bin/python scripts/mono_landmarks.py [--data ../shared/data/pose2sim-single]

The clip is Pose2Sim's single-person demo (four portrait cameras, 100 frames at 60 fps,
``../shared/data/pose2sim-single/README.md``). Every frame of ``cam01.mp4`` … ``cam04.mp4`` goes
through the ``mono`` source's own reader and detector (``VideoFrames``, ``PoseDetector``:
``mediapipe.solutions.pose.Pose(static_image_mode=False, model_complexity=1)``, the one
complexity whose model ships in the wheel), in video order, as the source runs it.

Keys, per camera ``<cam>`` in cam01..cam04 (float32 unless said):

- ``<cam>_image_px`` (frames, 33, 3): image landmarks in pixels, x right, y down; the third
  column is MediaPipe's relative depth scaled by the image width (as MediaPipe scales it);
- ``<cam>_world_m`` (frames, 33, 3): world landmarks in metres, origin between the hips,
  camera-tied axes (x right, y down, z away from the camera);
- ``<cam>_visibility`` (frames, 33): MediaPipe's visibility in [0, 1];
- ``<cam>_detected`` (frames,) bool: a body was found (rows are NaN / 0 where not);
- ``<cam>_size_wh`` (2,) int: the decoded frame's width and height in pixels.

Saved with ``numpy.savez_compressed`` (330 KB). Re-running it on this machine (x86-64, CPU)
reproduced the committed file bit for bit.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from skelfuse.agent.sources.mono_camera import PoseDetector, VideoFrames

ROOT = Path(__file__).resolve().parents[1]
CAMERAS = ("cam01", "cam02", "cam03", "cam04")


def landmarks_of(video: Path) -> dict[str, np.ndarray]:
    """The landmark arrays of one video, keyed without the camera prefix, through the ``mono``
    source's own reader and detector (agent/sources/mono_camera.py)."""
    frames, detector = VideoFrames(video), PoseDetector()
    image, world, visibility, detected = [], [], [], []
    width = height = 0
    while (bgr := frames.read()) is not None:
        height, width = bgr.shape[:2]
        found = detector.detect(bgr)
        if found is None:
            image.append(np.full((33, 3), np.nan, np.float32))
            world.append(np.full((33, 3), np.nan, np.float32))
            visibility.append(np.zeros(33, np.float32))
            detected.append(False)
            continue
        image.append(found.image_px)
        world.append(found.world_m)
        visibility.append(found.visibility)
        detected.append(True)
    detector.close()
    frames.close()
    return {
        "image_px": np.asarray(image, np.float32),
        "world_m": np.asarray(world, np.float32),
        "visibility": np.asarray(visibility, np.float32),
        "detected": np.asarray(detected, bool),
        "size_wh": np.asarray([width, height]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared/data/pose2sim-single")
    parser.add_argument("--out", type=Path, default=ROOT / "tests/data/mono_landmarks.npz")
    args = parser.parse_args()
    arrays: dict[str, np.ndarray] = {}
    for camera in CAMERAS:
        started = time.process_time()
        found = landmarks_of(args.data / f"{camera}.mp4")
        frames = len(found["detected"])
        cpu_ms = (time.process_time() - started) / max(frames, 1) * 1000
        print(f"{camera}: {int(found['detected'].sum())}/{frames} detected, {cpu_ms:.1f} ms CPU")
        arrays.update({f"{camera}_{key}": value for key, value in found.items()})
    np.savez_compressed(args.out, **arrays)


if __name__ == "__main__":
    main()
