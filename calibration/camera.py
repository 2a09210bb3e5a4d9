"""A calibrated RGB camera: intrinsics (pinhole + OpenCV distortion), its pose, projection.

API (used by :mod:`calibration.triangulation`, :mod:`calibration.camera_files`, the offline
mocap path and the accuracy benchmarks)::

    CameraIntrinsics(width, height, fx, fy, cx, cy, distortion)   validated at construction
    intrinsics.for_frames(width, height) -> (intrinsics, warning)  resized/cropped videos
    Camera(name, intrinsics, T_world_from_sensor)
    camera.project(points_world (..., 3) m) -> (..., 2) px       NaN behind the camera
    camera.normalized(image_px (..., 2) px) -> (..., 2)           undistorted x/z, y/z
    camera.T_opencv_from_world                                    (4, 4) for DLT rows
    pose_from_opencv_extrinsics(R or rvec, t) -> T_world_from_sensor  (x_cam = R·X + t)

Frames. Pixels follow OpenCV: +u right, +v down, the centre of the top-left pixel at (0, 0).
``T_world_from_sensor`` places the **sensor frame**, the one every skelfuse sensor reports joints
in (Kinect v2 camera space: +X sensor-left, +Y up, +Z forward, metres; conventions.md §1.7), so
an RGB camera sits in the same calibration as the Kinects. The OpenCV camera frame (+X right,
+Y down, +Z forward) is the sensor frame turned 180° about Z: :data:`SENSOR_FROM_OPENCV`.
The world is the project's: right-handed, +Y up, metres, floor at y = 0.

Distortion is OpenCV's model on normalised coordinates: ``(k1, k2, p1, p2[, k3[, k4, k5,
k6]])``; the rational denominator uses k4..k6. An empty tuple means no distortion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import InvalidInput
from skelfuse.protocol.transform import Matrix4, invert, is_rigid

FloatArray = npt.NDArray[np.float64]

SENSOR_FROM_OPENCV: Final[Matrix4] = np.diag([-1.0, -1.0, 1.0, 1.0])
"""``T_sensor_from_opencv``: the OpenCV camera frame in the skelfuse sensor frame (its own
inverse)."""

_DISTORTION_LENGTHS: Final = (0, 4, 5, 8)
_UNDISTORT_ITERATIONS: Final = 20
_MAX_CROP: Final = 0.02
"""Frames up to 2 % narrower or wider than the calibrated image are taken as a centred crop."""


@dataclass(frozen=True, slots=True)
class CameraIntrinsics:
    """Pinhole intrinsics in pixels of an image ``width`` × ``height`` as the frames arrive.

    Raises:
        InvalidInput: a size or focal length that is not positive, a NaN/inf, a principal
            point outside the image, or a distortion of another length than 0, 4, 5 or 8.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        numbers = (self.fx, self.fy, self.cx, self.cy, *self.distortion)
        if not all(np.isfinite(numbers)):
            raise InvalidInput(f"camera intrinsics hold NaN or inf: {self}")
        if self.width <= 0 or self.height <= 0:
            raise InvalidInput(f"image size must be positive, got {self.width}×{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise InvalidInput(f"focal lengths must be positive pixels, got {self.fx}, {self.fy}")
        if not (0 <= self.cx <= self.width and 0 <= self.cy <= self.height):
            raise InvalidInput(
                f"principal point ({self.cx:.1f}, {self.cy:.1f}) lies outside the "
                f"{self.width}×{self.height} image: is the image size (or its orientation) right?"
            )
        if len(self.distortion) not in _DISTORTION_LENGTHS:
            raise InvalidInput(
                f"distortion must hold 0, 4, 5 or 8 OpenCV coefficients (k1 k2 p1 p2 [k3 [k4 k5 "
                f"k6]]), got {len(self.distortion)}"
            )

    def for_frames(self, width: int, height: int) -> tuple[CameraIntrinsics, str | None]:
        """These intrinsics for frames of ``width`` × ``height`` pixels, and a warning when
        that took an assumption.

        The same size: unchanged. The same aspect ratio: scaled (a resized video). Up to 2 %
        off per axis: a centred crop or pad, the principal point shifted by half the
        difference (a warning says so: check it if the reprojection is poor).

        Raises:
            InvalidInput: the frames are turned against the calibration (portrait frames,
                landscape calibration or the reverse), or differ in any other way.
        """
        if (width, height) == (self.width, self.height):
            return self, None
        if width <= 0 or height <= 0:
            raise InvalidInput(f"frame size must be positive, got {width}×{height}")
        if (width > height) != (self.width > self.height) and width != height:
            raise InvalidInput(
                f"the frames are {width}×{height} but the calibration is {self.width}×"
                f"{self.height}: one is portrait, the other landscape; rotate the video or "
                "use the calibration of this orientation"
            )
        sx, sy = width / self.width, height / self.height
        if abs(sx / sy - 1) < 1e-3:
            scaled = CameraIntrinsics(
                width,
                height,
                self.fx * sx,
                self.fy * sy,
                (self.cx + 0.5) * sx - 0.5,  # pixel centres scale about the image corner
                (self.cy + 0.5) * sy - 0.5,
                self.distortion,
            )
            return scaled, None
        if abs(sx - 1) <= _MAX_CROP and abs(sy - 1) <= _MAX_CROP:
            dx, dy = (width - self.width) / 2, (height - self.height) / 2
            cropped = CameraIntrinsics(
                width, height, self.fx, self.fy, self.cx + dx, self.cy + dy, self.distortion
            )
            return cropped, (
                f"frames {width}×{height}, calibration {self.width}×{self.height}: taken as a "
                f"centred crop (principal point moved by {dx:+.1f}, {dy:+.1f} px)"
            )
        raise InvalidInput(
            f"the frames are {width}×{height} but the calibration is {self.width}×{self.height}: "
            "not a resize and not a small crop; calibrate at this resolution"
        )

    @property
    def matrix(self) -> FloatArray:
        """The (3, 3) camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_json(self) -> dict[str, Any]:
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "distortion": list(self.distortion),
        }

    @staticmethod
    def from_json(data: Any, origin: str) -> CameraIntrinsics:
        """Parse :meth:`to_json`'s form.

        Raises:
            InvalidInput: missing or mistyped fields, or values the constructor refuses; the
                message starts with ``origin``.
        """
        if not isinstance(data, dict):
            raise InvalidInput(f"{origin}: intrinsics must be an object")
        try:
            width, height = data["width"], data["height"]
            if not isinstance(width, int) or not isinstance(height, int):
                raise TypeError("width and height must be integers")
            distortion = data.get("distortion", [])
            if not isinstance(distortion, list):
                raise TypeError("distortion must be a list")
            return CameraIntrinsics(
                width,
                height,
                float(data["fx"]),
                float(data["fy"]),
                float(data["cx"]),
                float(data["cy"]),
                tuple(float(v) for v in distortion),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInput(f"{origin}: bad intrinsics ({exc})") from exc
        except InvalidInput as exc:
            raise InvalidInput(f"{origin}: {exc}") from exc

    def distort(self, xy: FloatArray) -> FloatArray:
        """Normalised undistorted (..., 2) coordinates → normalised distorted ones."""
        k = np.zeros(8)
        k[: len(self.distortion)] = self.distortion
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = (1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))) / (
            1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
        )
        xd = x * radial + 2 * k[2] * x * y + k[3] * (r2 + 2 * x * x)
        yd = y * radial + k[2] * (r2 + 2 * y * y) + 2 * k[3] * x * y
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_distorted: FloatArray) -> FloatArray:
        """Inverse of :meth:`distort` by fixed-point iteration (OpenCV's ``undistortPoints``
        scheme); exact to well below 0.01 px inside the image for ordinary lenses."""
        if not self.distortion:
            return xy_distorted
        xy = xy_distorted.copy()
        for _ in range(_UNDISTORT_ITERATIONS):
            error = self.distort(xy) - xy_distorted
            xy = xy - error
        return xy


@dataclass(frozen=True, slots=True)
class Camera:
    """One calibrated camera: ``T_world_from_sensor`` (4×4, metres, sensor frame as in the
    module docstring) and its intrinsics.

    Raises:
        InvalidInput: ``T_world_from_sensor`` is not a rigid 4×4 transform.
    """

    name: str
    intrinsics: CameraIntrinsics
    T_world_from_sensor: Matrix4

    def __post_init__(self) -> None:
        matrix = np.asarray(self.T_world_from_sensor, dtype=np.float64)
        if matrix.shape != (4, 4) or not is_rigid(matrix, atol=1e-5):
            raise InvalidInput(f"camera {self.name!r}: T_world_from_sensor is not a rigid 4×4")
        object.__setattr__(self, "T_world_from_sensor", matrix)

    @property
    def T_opencv_from_world(self) -> Matrix4:
        """World → OpenCV camera frame (the ``[R | t]`` of a projection matrix)."""
        return SENSOR_FROM_OPENCV @ invert(self.T_world_from_sensor)

    def normalized(self, image_px: npt.ArrayLike) -> FloatArray:
        """(..., 2) pixels → (..., 2) undistorted normalised coordinates (x/z, y/z, OpenCV)."""
        uv = np.asarray(image_px, dtype=np.float64)
        k = self.intrinsics
        distorted = np.stack([(uv[..., 0] - k.cx) / k.fx, (uv[..., 1] - k.cy) / k.fy], axis=-1)
        return k.undistort(distorted)

    def project(self, points_world: npt.ArrayLike) -> FloatArray:
        """(..., 3) world points (metres) → (..., 2) pixels, distortion applied; NaN for points
        at or behind the camera's centre plane."""
        points = np.asarray(points_world, dtype=np.float64)
        transform = self.T_opencv_from_world
        cam = points @ transform[:3, :3].T + transform[:3, 3]
        z = cam[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = cam[..., :2] / np.where(z > 1e-9, z, np.nan)[..., None]
        k = self.intrinsics
        xy = k.distort(xy)
        return np.stack([k.fx * xy[..., 0] + k.cx, k.fy * xy[..., 1] + k.cy], axis=-1)


def pose_from_opencv_extrinsics(rotation: npt.ArrayLike, translation_m: npt.ArrayLike) -> Matrix4:
    """``T_world_from_sensor`` from OpenCV's world → camera ``R`` (3×3, or a Rodrigues 3-vector)
    and ``t`` (metres): ``x_cam = R·X + t``.

    Raises:
        InvalidInput: a rotation of another shape, not orthonormal, or NaN.
    """
    rot = np.asarray(rotation, dtype=np.float64)
    if rot.size == 3:
        rot = rodrigues(rot.reshape(3))
    if rot.shape != (3, 3) or not np.isfinite(rot).all():
        raise InvalidInput(f"rotation: expected 3×3 or a Rodrigues 3-vector, got {rot.shape}")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5) or np.linalg.det(rot) < 0:
        raise InvalidInput("rotation is not a proper rotation (orthonormal, determinant +1)")
    t = np.asarray(translation_m, dtype=np.float64).reshape(-1)
    if t.shape != (3,) or not np.isfinite(t).all():
        raise InvalidInput(f"translation: expected 3 finite numbers, got {t.shape}")
    opencv_from_world = np.eye(4)
    opencv_from_world[:3, :3] = rot
    opencv_from_world[:3, 3] = t
    world_from_opencv = np.linalg.inv(opencv_from_world)
    return np.asarray(world_from_opencv @ SENSOR_FROM_OPENCV, dtype=np.float64)


def rodrigues(vector: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Rotation matrix of a Rodrigues (axis × angle in radians) 3-vector, like ``cv2.Rodrigues``."""
    v = np.asarray(vector, dtype=np.float64).reshape(3)
    angle = float(np.linalg.norm(v))
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation: npt.NDArray[np.float64] = (
        np.eye(3) + math.sin(angle) * cross + (1 - math.cos(angle)) * (cross @ cross)
    )
    return rotation
