"""The detection stage of ``skelfuse mocap``: videos → MediaPipe pose landmarks, in the mono env.

MediaPipe 0.10.21 pins numpy<2, so it lives in its own environment (``scripts/venv_mono.sh``
makes ``.venv-mono``) while fusion and the exporters run in the main one. ``skelfuse mocap``
runs this module there as a child process::

    .venv-mono/bin/python -m skelfuse.cli.mocap_detect --out LANDMARKS.npz VIDEO [VIDEO ...]

It writes the landmarks in the layout of ``tests/data/mono_landmarks.npz`` (keys
``<name>_image_px``, ``_world_m``, ``_visibility``, ``_detected``, ``_size_wh``, plus
``<name>_fps``, the video's frame rate), ``<name>`` being each video's file stem, and reports on
stdout one JSON object per line, which the parent turns into progress and errors:

- ``{"video": i, "total": N}`` for every video before any detection (N frames by its header, 0
  if unknown), so a video that does not open fails at once;
- ``{"video": i, "done": n}`` every few frames and at its end;
- ``{"error": "..."}`` then exit status 1 when a video cannot be read.

Only numpy, OpenCV and MediaPipe are imported: nothing from the server side.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

LANDMARKS = 33
REPORT_EVERY = 5
"""Frames between progress lines (a line costs microseconds; a frame ~30 ms)."""


def _say(message: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()


def _open(video: Path) -> Any:
    """An opened ``cv2.VideoCapture``.

    Raises:
        OSError: OpenCV cannot open the file as a video.
    """
    import cv2  # type: ignore[import-not-found,unused-ignore]  # the mono env only

    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise OSError(f"{video}: not a video OpenCV can open")
    return capture


def frame_count(video: Path) -> int:
    """Frames in the video by its header (0 when it does not say).

    Raises:
        OSError: OpenCV cannot open the file as a video.
    """
    import cv2  # type: ignore[import-not-found,unused-ignore]  # the mono env only

    capture = _open(video)
    try:
        return max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
    finally:
        capture.release()


def detect(video: Path, index: int) -> dict[str, np.ndarray]:
    """Landmarks of every frame of one video (keys without the name prefix).

    Raises:
        OSError: the file cannot be opened or decoded as a video.
    """
    import cv2  # type: ignore[import-not-found,unused-ignore]  # the mono env only
    import mediapipe as mp  # type: ignore[import-not-found,unused-ignore]  # the mono env only

    capture = _open(video)
    fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
    image: list[Any] = []
    world: list[Any] = []
    visibility: list[Any] = []
    detected: list[bool] = []
    width = height = 0
    # The one model complexity whose weights ship in the wheel (others download: forbidden).
    with mp.solutions.pose.Pose(static_image_mode=False, model_complexity=1) as pose:
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            height, width = frame.shape[:2]
            result = pose.process(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
            if result.pose_landmarks is None:
                image.append(np.full((LANDMARKS, 3), np.nan))
                world.append(np.full((LANDMARKS, 3), np.nan))
                visibility.append(np.zeros(LANDMARKS))
                detected.append(False)
            else:
                marks = result.pose_landmarks.landmark
                image.append([[p.x * width, p.y * height, p.z * width] for p in marks])
                world.append([[p.x, p.y, p.z] for p in result.pose_world_landmarks.landmark])
                visibility.append([p.visibility for p in marks])
                detected.append(True)
            if len(detected) % REPORT_EVERY == 0:
                _say({"video": index, "done": len(detected)})
    capture.release()
    if not detected:
        raise OSError(f"{video}: no frame could be decoded (not a video, or a codec OpenCV lacks)")
    if len(detected) % REPORT_EVERY:
        _say({"video": index, "done": len(detected)})
    return {
        "image_px": np.asarray(image, np.float32).reshape(-1, LANDMARKS, 3),
        "world_m": np.asarray(world, np.float32).reshape(-1, LANDMARKS, 3),
        "visibility": np.asarray(visibility, np.float32).reshape(-1, LANDMARKS),
        "detected": np.asarray(detected, bool),
        "size_wh": np.asarray([width, height]),
        "fps": np.asarray(fps),
    }


def main(argv: list[str] | None = None) -> int:
    """Detect every video, write the landmarks file; 0, or 1 after an ``error`` line."""
    parser = argparse.ArgumentParser(prog="python -m skelfuse.cli.mocap_detect")
    parser.add_argument("--out", type=Path, required=True, help="the .npz to write")
    parser.add_argument("videos", nargs="+", type=Path)
    args = parser.parse_args(argv)
    arrays: dict[str, Any] = {}
    try:
        for index, video in enumerate(args.videos):
            _say({"video": index, "total": frame_count(video)})
        for index, video in enumerate(args.videos):
            found = detect(video, index)
            arrays.update({f"{video.stem}_{key}": value for key, value in found.items()})
    except OSError as exc:
        _say({"error": str(exc)})
        return 1
    np.savez_compressed(args.out, **arrays)
    return 0


if __name__ == "__main__":
    sys.exit(main())
