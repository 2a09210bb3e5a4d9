"""Camera geometry for the mono accuracy benchmark: pinhole cameras with OpenCV's distortion
model, projection, undistortion, multi-view triangulation (DLT) and a small PnP.

Frames: the OpenCV camera frame (+X right, +Y down, +Z forward, metres) and skelfuse's world
frame (+Y up, metres; ``protocol/skeleton.py``). :func:`load_qca` reads a Qualisys ``.qca.txt``
calibration (Z up, millimetres) into that world frame; it is the benchmark's own reader until
the product's importer (issue 14 item 5) lands, and follows Pose2Sim's ``calib_qca_fun``: the
transform is the camera's pose in the room, its camera looks along its own -Z with +Y up, so a
half turn about X gives OpenCV's axes.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

WORLD_FROM_QUALISYS = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Qualisys (Z up) → skelfuse world (Y up): (x, y, z) → (x, z, -y); a proper rotation."""
CV_FROM_KINECT = np.diag([-1.0, -1.0, 1.0])
"""Kinect sensor frame (+X left, +Y up) → OpenCV camera frame (+X right, +Y down); self-inverse."""


@dataclass(frozen=True)
class Camera:
    """A calibrated camera.

    K: (3, 3) intrinsics, pixels. dist: (5,) k1, k2, p1, p2, k3 (OpenCV's order).
    R, t: world → OpenCV camera, ``p_cam = R @ p_world + t`` (metres). size_wh: image size.
    """

    name: str
    K: FloatArray
    dist: FloatArray
    R: FloatArray
    t: FloatArray
    size_wh: tuple[int, int]

    def world_from_camera(self) -> FloatArray:
        """(4, 4) ``T_world_from_camera`` for OpenCV camera-frame points."""
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = -self.R.T @ self.t
        return T

    def world_from_kinect(self) -> FloatArray:
        """(4, 4) ``T_world_from_sensor`` for Kinect sensor-frame points (what agents send)."""
        T = self.world_from_camera()
        T[:3, :3] = T[:3, :3] @ CV_FROM_KINECT
        return T


def load_qca(path: Path, distortion_scale: float = 1.0 / 64.0) -> dict[str, Camera]:
    """Cameras of a Qualisys ``.qca.txt`` file by serial, in skelfuse's world frame.

    ``distortion_scale``: Pose2Sim divides the file's distortion terms by 64 like the other
    intrinsics; the benchmark does the same (the triangulation residual is lower that way).

    Raises:
        ValueError: a camera lacks its transform or intrinsic element.
        OSError, xml.etree.ElementTree.ParseError: the file is unreadable.
    """
    cameras: dict[str, Camera] = {}
    for cam in ET.parse(path).getroot().iter("camera"):
        name = cam.get("serial", "")
        tr, intr, fov = cam.find("transform"), cam.find("intrinsic"), cam.find("fov_video")
        if tr is None or intr is None or fov is None:
            raise ValueError(f"{path}: camera {name!r} lacks transform/intrinsic/fov_video")
        f = {k: float(v) for k, v in intr.attrib.items() if k != "model"}
        left, top = float(fov.get("left", 0)), float(fov.get("top", 0))
        K = np.array([[f["focalLengthU"] / 64, 0.0, f["centerPointU"] / 64 - left],
                      [0.0, f["focalLengthV"] / 64, f["centerPointV"] / 64 - top],
                      [0.0, 0.0, 1.0]])  # fmt: skip
        dist = distortion_scale * np.array([f["radialDistortion1"], f["radialDistortion2"],
                                            f["tangentalDistortion1"], f["tangentalDistortion2"],
                                            f["radialDistortion3"]])  # fmt: skip
        rot = np.array([[float(tr.get(f"r{i}{j}", "nan")) for j in (1, 2, 3)] for i in (1, 2, 3)])
        pos = np.array([float(tr.get(a, "nan")) for a in ("x", "y", "z")]) / 1000.0
        # The rows of the file's matrix are the camera's axes in the room; a half turn about X
        # makes them OpenCV's.
        cam_axes_world = WORLD_FROM_QUALISYS @ rot.T @ np.diag([1.0, -1.0, -1.0])
        R = cam_axes_world.T
        size = (
            int(float(fov.get("right", 0)) - left + 1),
            int(float(fov.get("bottom", 0)) - top + 1),
        )
        cameras[name] = Camera(name, K, dist, R, -R @ (WORLD_FROM_QUALISYS @ pos), size)
    return cameras


def distort(xy: FloatArray, dist: FloatArray) -> FloatArray:
    """Normalised image coordinates (..., 2) through OpenCV's distortion model."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort(px: FloatArray, cam: Camera, iterations: int = 10) -> FloatArray:
    """Pixels (..., 2) → undistorted normalised coordinates (..., 2) (fixed-point iteration,
    as ``cv2.undistortPoints``; distortion here is a few pixels, so 10 rounds converge)."""
    K = cam.K
    xd = np.stack([(px[..., 0] - K[0, 2]) / K[0, 0], (px[..., 1] - K[1, 2]) / K[1, 1]], axis=-1)
    xy = xd.copy()
    for _ in range(iterations):
        xy = xy + (xd - distort(xy, cam.dist))
    return xy


def project(points_world: FloatArray, cam: Camera) -> FloatArray:
    """World points (..., 3) → pixels (..., 2); points behind the camera give NaN."""
    p = points_world @ cam.R.T + cam.t
    z = np.where(p[..., 2] > 1e-6, p[..., 2], np.nan)
    xy = distort(p[..., :2] / z[..., None], cam.dist)
    return np.stack([cam.K[0, 0] * xy[..., 0] + cam.K[0, 2],
                     cam.K[1, 1] * xy[..., 1] + cam.K[1, 2]], axis=-1)  # fmt: skip


def triangulate(px: FloatArray, weights: FloatArray, cams: list[Camera]) -> FloatArray:
    """Weighted DLT over the views: px (V, N, 2) pixels, weights (V, N) ≥ 0 → (N, 3) world.

    A point with fewer than two views of positive weight is NaN.
    """
    rows = []
    for v, cam in enumerate(cams):
        P = np.hstack([cam.R, cam.t[:, None]])
        xy = undistort(px[v], cam)
        w = np.nan_to_num(weights[v])[:, None]
        rows.append(w * (xy[:, :1] * P[2] - P[0]))
        rows.append(w * (xy[:, 1:] * P[2] - P[1]))
    A = np.nan_to_num(np.stack(rows, axis=1))  # (N, 2V, 4)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1, :]
    out = X[:, :3] / X[:, 3:]
    seen = (np.nan_to_num(weights) > 0).sum(axis=0) >= 2
    return np.where(seen[:, None], out, np.nan)


def pnp(
    px: FloatArray, local: FloatArray, cam: Camera, iterations: int = 15
) -> tuple[FloatArray, FloatArray]:
    """Rotation and translation placing ``local`` (N, 3) points (camera-like axes, metres) so
    they project onto ``px`` (N, 2): Gauss-Newton on the undistorted reprojection error from
    R = I and the linear translation. Returns (R (3, 3), t (3,)), camera = R @ local + t."""
    xy = undistort(px, cam)
    ok = np.isfinite(xy).all(axis=1) & np.isfinite(local).all(axis=1)
    xy, X = xy[ok], local[ok]
    # (x·(Z+tz) − (X+tx)) = 0 and likewise for y: linear in t with R = I.
    n = len(X)
    A = np.zeros((2 * n, 3))
    A[:n, 0], A[:n, 2], A[n:, 1], A[n:, 2] = -1, xy[:, 0], -1, xy[:, 1]
    b = np.concatenate([X[:, 0] - xy[:, 0] * X[:, 2], X[:, 1] - xy[:, 1] * X[:, 2]])
    t = np.linalg.lstsq(A, b, rcond=None)[0]
    R = np.eye(3)
    for _ in range(iterations):
        p = X @ R.T + t
        z = p[:, 2]
        res = np.concatenate([p[:, 0] / z - xy[:, 0], p[:, 1] / z - xy[:, 1]])
        # d(p)/d(omega) = -[p - t]_x; d(p)/dt = I; then the projection's Jacobian.
        q = p - t
        dp = np.zeros((n, 3, 6))
        dp[:, :, 3:] = np.eye(3)
        dp[:, 0, 1], dp[:, 0, 2] = q[:, 2], -q[:, 1]
        dp[:, 1, 0], dp[:, 1, 2] = -q[:, 2], q[:, 0]
        dp[:, 2, 0], dp[:, 2, 1] = q[:, 1], -q[:, 0]
        jx = (dp[:, 0] - (p[:, 0] / z)[:, None] * dp[:, 2]) / z[:, None]
        jy = (dp[:, 1] - (p[:, 1] / z)[:, None] * dp[:, 2]) / z[:, None]
        step = np.linalg.lstsq(np.vstack([jx, jy]), -res, rcond=None)[0]
        R = _rodrigues(step[:3]) @ R
        t = t + step[3:]
    return R, t


def _rodrigues(w: FloatArray) -> FloatArray:
    """Rotation matrix of the rotation vector ``w`` (radians)."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3)
    k = w / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rot = np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx
    return np.asarray(rot, dtype=np.float64)
