"""The product's camera modules as the mono accuracy benchmark uses them.

Cameras come from the clip's Qualisys file through ``skelfuse calibration``'s reader
(:func:`skelfuse.calibration.camera_files.read_camera_file`), in the project's world (+Y up,
metres); projection (with distortion) is :meth:`skelfuse.calibration.camera.Camera.project`.
MediaPipe's landmarks are placed in a camera by :mod:`skelfuse.protocol.mediapipe_pose`, whose
pinhole model has no distortion: the benchmark undistorts the image landmarks first, as the
module asks of a calibration with distortion.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.camera import SENSOR_FROM_OPENCV, Camera
from skelfuse.calibration.camera_files import read_camera_file
from skelfuse.geometry.pinhole import Intrinsics

FloatArray = npt.NDArray[np.float64]


def load_cameras(path: Path) -> dict[str, Camera]:
    """The cameras of a Qualisys ``.qca.txt`` file by name.

    Raises:
        skelfuse.calibration.camera_files.CameraFileError: the file is unreadable or invalid.
    """
    return {camera.name: camera for camera in read_camera_file(path, "qualisys").cameras}


def pinhole(camera: Camera) -> Intrinsics:
    """The camera's intrinsics without distortion (for landmarks undistorted first)."""
    k = camera.intrinsics
    return Intrinsics(k.fx, k.fy, k.cx, k.cy)


def undistorted_px(camera: Camera, image_px: FloatArray) -> FloatArray:
    """Pixels as detected (..., 2) → the pixels an ideal pinhole camera would see (..., 2)."""
    xy = camera.normalized(image_px)
    k = camera.intrinsics
    return np.stack([k.fx * xy[..., 0] + k.cx, k.fy * xy[..., 1] + k.cy], axis=-1)


def opencv_to_world(camera: Camera, points_cv: FloatArray) -> FloatArray:
    """Points in the camera's OpenCV frame (..., 3) → world (..., 3), metres."""
    T = camera.T_world_from_sensor @ SENSOR_FROM_OPENCV
    return np.asarray(points_cv @ T[:3, :3].T + T[:3, 3], dtype=np.float64)
