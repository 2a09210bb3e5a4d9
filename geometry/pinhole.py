"""A pinhole camera's intrinsics: what turns metres in the camera frame into pixels.

The camera frame here is OpenCV's (and MediaPipe's): +X right, +Y down, +Z forward along the
optical axis, metres; pixels have x right, y down, as ``cv2.projectPoints`` gives them with no
distortion (MediaPipe's landmarks scaled by the image size put the image's edge at 0, OpenCV the
first pixel's centre: half a pixel, far below the landmarks' noise). Lens distortion is not
modelled here: a calibration with distortion (calibration/camera.py) undistorts the landmarks
before they get here (the ``mono`` source's ``--calibration``).

The sensor frame of the wire (Kinect v2's: +X left, +Y up, +Z forward) is this frame turned
180° about Z: :data:`CV_TO_SENSOR` (``p_sensor = CV_TO_SENSOR * p_cv``).

Used by :mod:`skelfuse.geometry.pnp` (placing a body in the camera), the ``mono`` agent source
(``--intrinsics fx,fy,cx,cy`` or ``--fov``) and anything else that projects joints into an
ordinary camera (calibration, benchmarks): it is here, in the lowest layer, so every layer can.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

CV_TO_SENSOR: Final = np.array([-1.0, -1.0, 1.0])
"""Per-axis signs from the OpenCV/MediaPipe camera frame to the wire's sensor frame (and back:
the map is its own inverse)."""


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Focal lengths and principal point, in pixels (no distortion).

    fx, fy: focal lengths in pixels; cx, cy: the principal point in pixels.
    """

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in values) or self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"intrinsics need finite values and positive focal lengths: {values}")

    @classmethod
    def parse(cls, text: str) -> Intrinsics:
        """From ``"fx,fy,cx,cy"`` (pixels), as the command line gives them.

        Raises:
            ValueError: not four comma-separated numbers, or not valid intrinsics.
        """
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != 4:
            raise ValueError(f"expected fx,fy,cx,cy (four numbers in pixels), got {text!r}")
        try:
            fx, fy, cx, cy = (float(p) for p in parts)
        except ValueError:
            raise ValueError(
                f"expected fx,fy,cx,cy (four numbers in pixels), got {text!r}"
            ) from None
        return cls(fx, fy, cx, cy)

    @classmethod
    def from_fov(cls, width: int, height: int, horizontal_fov_deg: float) -> Intrinsics:
        """A guess from the image size and the horizontal field of view: square pixels, the
        principal point at the image centre. Depth from one camera scales with the focal length,
        so a wrong field of view scales every distance: prefer measured intrinsics.

        Args:
            width, height: image size in pixels.
            horizontal_fov_deg: the full horizontal angle of view, degrees, in (0, 180).

        Raises:
            ValueError: on a non-positive size or a field of view outside (0, 180).
        """
        if width <= 0 or height <= 0:
            raise ValueError(f"image size must be positive, got {width}x{height}")
        if not 0.0 < horizontal_fov_deg < 180.0:
            raise ValueError(f"field of view must be in (0, 180) degrees, got {horizontal_fov_deg}")
        focal = (width / 2.0) / math.tan(math.radians(horizontal_fov_deg) / 2.0)
        return cls(focal, focal, width / 2.0, height / 2.0)

    def matrix(self) -> FloatArray:
        """The 3×3 camera matrix K (OpenCV's layout)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, points_cv: npt.ArrayLike) -> FloatArray:
        """Pixels of camera-frame points.

        Args:
            points_cv: (..., 3) metres, OpenCV camera frame (+Z forward).

        Returns:
            (..., 2) float64 pixels; NaN or ±inf for points at or behind z = 0.
        """
        p = np.asarray(points_cv, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = self.fx * p[..., 0] / p[..., 2] + self.cx
            y = self.fy * p[..., 1] / p[..., 2] + self.cy
        out: FloatArray = np.stack([x, y], axis=-1)
        return out

    def rays(self, pixels: npt.ArrayLike) -> FloatArray:
        """Unit viewing rays (OpenCV camera frame) through pixels.

        Args:
            pixels: (..., 2) pixel coordinates.

        Returns:
            (..., 3) float64 unit vectors, +Z forward.
        """
        px = np.asarray(pixels, dtype=np.float64)
        d = np.stack(
            [
                (px[..., 0] - self.cx) / self.fx,
                (px[..., 1] - self.cy) / self.fy,
                np.ones(px.shape[:-1]),
            ],
            axis=-1,
        )
        unit: FloatArray = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return unit
