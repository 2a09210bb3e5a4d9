"""What the ``mono`` source reads and runs: video frames (OpenCV) and MediaPipe Pose.

Both libraries live in the ``mono`` environment only (``scripts/venv_mono.sh``: mediapipe 0.10.21
pins numpy<2) and are imported when a reader or detector is made, never at import of this module,
so ``skelfuse doctor`` and the registry can look at them without loading them.

- :class:`VideoFrames`: a webcam (``--camera N``) or a file (``--video FILE``) through
  ``cv2.VideoCapture``; BGR uint8 images.
- :class:`PoseDetector`: ``mediapipe.solutions.pose.Pose(static_image_mode=False,
  model_complexity=1)``, the one model whose weights ship in the wheel
  (``modules/pose_landmark/pose_landmark_full.tflite`` with ``pose_detection.tflite``): it never
  downloads anything. Complexities 0 and 2 would try to download their models, so they are not
  offered. One person per image (the solution's limit).
- :func:`check_mono`: whether both can run here, and why not, without importing them.

The frames and landmarks go to :mod:`skelfuse.protocol.mediapipe_pose` (pure numpy).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sources.base import SensorError

MEDIAPIPE_VERSION: Final = "0.10.21"
"""The version whose wheel ships the pose models (newer ones ship none)."""
MODEL_FILES: Final = (
    "modules/pose_detection/pose_detection.tflite",
    "modules/pose_landmark/pose_landmark_full.tflite",
)
"""The model files ``model_complexity=1`` loads, relative to the mediapipe package."""


@dataclass(frozen=True, slots=True)
class Landmarks:
    """One person's MediaPipe Pose output for one image.

    image_px: (33, 3) float32: x, y in pixels (right, down) and MediaPipe's relative depth
        scaled by the image width. world_m: (33, 3) float32 metres, hip-centred, camera axes
        (+X right, +Y down, +Z away). visibility: (33,) float32 in [0, 1].
    """

    image_px: npt.NDArray[np.float32]
    world_m: npt.NDArray[np.float32]
    visibility: npt.NDArray[np.float32]


class FrameReader(Protocol):
    """Where images come from (:class:`VideoFrames`; tests pass their own)."""

    @property
    def fps(self) -> float | None:
        """Frames per second the device or file reports, None if it reports none."""
        ...

    def read(self) -> npt.NDArray[np.uint8] | None:
        """The next (H, W, 3) BGR image, or None at the end of a file / on a camera error."""
        ...

    def rewind(self) -> bool:
        """Back to the first frame (files); False if the reader cannot."""
        ...

    def close(self) -> None: ...


class Detector(Protocol):
    """Landmarks of the one person in an image (:class:`PoseDetector`; tests pass their own)."""

    def detect(self, bgr: npt.NDArray[np.uint8]) -> Landmarks | None: ...

    def close(self) -> None: ...


class VideoFrames:
    """Frames of a webcam (an int index) or a video file (a path), through OpenCV.

    Raises:
        SensorError: OpenCV is missing, or the camera / file does not open.
    """

    def __init__(self, source: int | str | Path) -> None:
        cv2 = _import("cv2", "opencv-python-headless")
        self._is_file = not isinstance(source, int)
        if not isinstance(source, int) and not Path(source).is_file():
            raise SensorError(f"video file not found: {source}")
        self._capture: Any = cv2.VideoCapture(str(source) if self._is_file else source)
        if not self._capture.isOpened():
            what = f"video file {source}" if self._is_file else f"camera {source}"
            raise SensorError(f"OpenCV could not open {what}")
        fps = float(self._capture.get(cv2.CAP_PROP_FPS) or 0.0)
        self._fps = fps if 0.0 < fps < 1000.0 else None
        self._cv2 = cv2

    @property
    def fps(self) -> float | None:
        return self._fps

    def read(self) -> npt.NDArray[np.uint8] | None:
        ok, image = self._capture.read()
        return image if ok else None

    def rewind(self) -> bool:
        return self._is_file and bool(self._capture.set(self._cv2.CAP_PROP_POS_FRAMES, 0))

    def close(self) -> None:
        self._capture.release()


class PoseDetector:
    """MediaPipe Pose in video mode (landmarks tracked from frame to frame).

    Raises:
        SensorError: mediapipe (or numpy<2 for it) is missing, or its model files are absent.
    """

    def __init__(self) -> None:
        check = check_mono()
        if not check[0]:
            raise SensorError(f"the mono source cannot run here: {check[1]}")
        mp = _import("mediapipe", f"mediapipe=={MEDIAPIPE_VERSION}")
        self._pose: Any = mp.solutions.pose.Pose(
            static_image_mode=False, model_complexity=1, smooth_landmarks=True
        )

    def detect(self, bgr: npt.NDArray[np.uint8]) -> Landmarks | None:
        """The person's landmarks in a BGR image (OpenCV's channel order), or None."""
        height, width = bgr.shape[:2]
        rgb = np.ascontiguousarray(bgr[..., ::-1])  # the same bytes as cv2.cvtColor(BGR2RGB)
        result = self._pose.process(rgb)
        if result.pose_landmarks is None or result.pose_world_landmarks is None:
            return None
        marks = result.pose_landmarks.landmark
        image = np.array([(p.x * width, p.y * height, p.z * width) for p in marks], np.float32)
        world = np.array(
            [(p.x, p.y, p.z) for p in result.pose_world_landmarks.landmark], np.float32
        )
        visibility = np.array([p.visibility for p in marks], np.float32)
        return Landmarks(image, world, visibility)

    def close(self) -> None:
        self._pose.close()


def check_mono() -> tuple[bool, str]:
    """(can run, why): mediapipe 0.10.21 with its model files, numpy<2, protobuf<5 and OpenCV,
    looked up without importing them (``skelfuse doctor``)."""
    try:
        spec = importlib.util.find_spec("mediapipe")
    except (ImportError, ValueError):
        spec = None
    install = "make the mono environment: scripts/venv_mono.sh (or pip install 'skelfuse[mono]')"
    if spec is None or not spec.submodule_search_locations:
        return False, f"missing mediapipe: {install}"
    version = importlib.metadata.version("mediapipe")
    if version != MEDIAPIPE_VERSION:
        return False, (
            f"mediapipe {version} found; only {MEDIAPIPE_VERSION} ships the pose models "
            f"(no download at run time): {install}"
        )
    if int(np.__version__.split(".")[0]) >= 2:
        return (
            False,
            f"numpy {np.__version__}: mediapipe {MEDIAPIPE_VERSION} needs numpy<2; {install}",
        )
    try:
        protobuf = importlib.metadata.version("protobuf")
    except importlib.metadata.PackageNotFoundError:
        return False, f"missing protobuf (<5, for mediapipe {MEDIAPIPE_VERSION}): {install}"
    if int(protobuf.split(".")[0]) >= 5:
        return (
            False,
            f"protobuf {protobuf}: mediapipe {MEDIAPIPE_VERSION} needs protobuf<5; {install}",
        )
    package = Path(next(iter(spec.submodule_search_locations)))
    missing = [name for name in MODEL_FILES if not (package / name).is_file()]
    if missing:
        return False, f"model files missing from the mediapipe wheel: {', '.join(missing)}"
    try:
        cv2_found = importlib.util.find_spec("cv2") is not None
    except (ImportError, ValueError):
        cv2_found = False
    if not cv2_found:
        return False, "missing OpenCV (cv2): pip install opencv-python-headless"
    return True, (
        f"mediapipe {version} with its pose models, numpy {np.__version__}, protobuf {protobuf}, "
        "OpenCV found"
    )


def _import(module: str, package: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise SensorError(f"the mono source needs {package}: {exc}") from exc
