"""A Kinect v2-like depth camera: intrinsics, pixel rays, its error model, back-projection.

:mod:`agent.sim.room` ray casts the scene through :func:`pixel_rays` and hands the ideal image
to :func:`sensor_effects`; :func:`depth_to_points` and :func:`voxel_downsample` turn an image into
the point cloud an agent sends.

Frames: depth images and point clouds are in the sensor's Kinect camera frame (+X sensor-LEFT,
+Y up, +Z forward, metres), like the skeletons of :mod:`agent.sim.kinect_model`.

Pixel convention: pixel (u, v) (column, row; integer indices are pixel centres) sees the
camera-frame direction ``(-(u - cx)/fx, -(v - cy)/fy, 1)``: u grows towards the sensor's right
(−X), v grows downwards (−Y). A depth value is the Z coordinate (not the ray length), as the
Kinect reports it; 0 means no reading.

Depth model (each effect is a parameter of :class:`DepthNoise`):

- noise: Gaussian along Z with σ = 1.5 mm + 1.5 mm·z² (z in metres: 3 mm at 1 m, 7.5 mm at
  2 m, 25 mm at 4 m). Kinect v2 time-of-flight studies report 1–2 mm at 1 m, growing roughly
  with the square of depth; the figure is deliberately on the pessimistic side.
- range: readings outside 0.5–4.5 m are missing (the specified reliable range).
- grazing angles: surfaces seen at more than ~81° from their normal return nothing (applied by
  the ray caster, which knows the surface normals).
- depth discontinuities: pixels whose depth differs from a 4-neighbour by more than 4 % are
  dropped (the SDK removes "flying pixels" at object edges).
- random dropout: 2 % of the remaining pixels (dark or specular spots, multipath).

This module must stay importable on a sensor PC: numpy only, no scipy or open3d.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class DepthIntrinsics:
    """Pinhole depth camera: image size (pixels), focal lengths and principal point (pixels),
    and the range (metres) outside which readings are missing."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    min_m: float
    max_m: float


KINECT_V2_DEPTH: Final = DepthIntrinsics(
    width=512, height=424, fx=365.5, fy=365.5, cx=256.0, cy=212.0, min_m=0.5, max_m=4.5
)
"""Typical Kinect v2 factory depth intrinsics (512×424, f ≈ 365 px, i.e. 70.6° × 60° field of
view; individual units differ by a few pixels) and its specified 0.5–4.5 m range."""


@dataclass(frozen=True, slots=True)
class DepthNoise:
    """Depth error model (see the module docstring for the sources of the magnitudes)."""

    sigma_base_m: float = 0.0015
    sigma_per_m2: float = 0.0015
    dropout: float = 0.02
    max_incidence_deg: float = 81.0
    edge_jump_fraction: float = 0.04


def pixel_rays(intrinsics: DepthIntrinsics) -> FloatArray:
    """(H, W, 3) camera-frame ray directions with Z = 1 (so a point at depth z is z·ray)."""
    u = np.arange(intrinsics.width, dtype=np.float64)
    v = np.arange(intrinsics.height, dtype=np.float64)
    uu, vv = np.meshgrid(u, v)
    rays = np.empty((intrinsics.height, intrinsics.width, 3))
    rays[..., 0] = -(uu - intrinsics.cx) / intrinsics.fx
    rays[..., 1] = -(vv - intrinsics.cy) / intrinsics.fy
    rays[..., 2] = 1.0
    return rays


def sensor_effects(
    depth: FloatArray,
    intrinsics: DepthIntrinsics,
    model: DepthNoise,
    rng: np.random.Generator | None,
) -> npt.NDArray[np.float32]:
    """What the sensor makes of an ideal depth image: edge loss, noise, dropout, range.

    Args:
        depth: (height, width) ideal depth (Z, metres), 0 = nothing hit.
        intrinsics: the camera's range.
        model: the error model.
        rng: random generator for noise and dropout; None leaves both out.

    Returns:
        (height, width) float32 depth in metres, 0 = no reading.
    """
    depth = _drop_edges(depth, model.edge_jump_fraction)
    if rng is not None:
        sigma = model.sigma_base_m + model.sigma_per_m2 * depth**2
        depth = np.where(depth > 0, depth + rng.normal(size=depth.shape) * sigma, 0.0)
        depth[rng.random(depth.shape) < model.dropout] = 0.0
    depth[(depth < intrinsics.min_m) | (depth > intrinsics.max_m)] = 0.0
    image: npt.NDArray[np.float32] = depth.astype(np.float32)
    return image


def _drop_edges(depth: FloatArray, jump_fraction: float) -> FloatArray:
    """Zero pixels whose depth differs from a 4-neighbour by more than ``jump_fraction``·z."""
    padded = np.pad(depth, 1, mode="edge")
    centre = padded[1:-1, 1:-1]
    jump = np.zeros_like(depth)
    for neighbour in (padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]):
        jump = np.maximum(jump, np.abs(neighbour - centre))
    out = depth.copy()
    out[jump > jump_fraction * np.maximum(depth, 1e-6)] = 0.0
    return out


def depth_to_points(
    depth: npt.ArrayLike, intrinsics: DepthIntrinsics = KINECT_V2_DEPTH
) -> npt.NDArray[np.float32]:
    """Back-project a depth image into the Kinect camera frame.

    Args:
        depth: (height, width) depth in metres (Z), 0 or non-finite = no reading.

    Returns:
        (N, 3) float32 points, one per valid pixel, Kinect camera frame (+X sensor-left, +Y up,
        +Z forward): ``x = -(u - cx)·z/fx``, ``y = -(v - cy)·z/fy``.

    Raises:
        ValueError: when the image size does not match the intrinsics.
    """
    image = np.asarray(depth, dtype=np.float64)
    if image.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth image shape {image.shape} does not match the intrinsics "
            f"({intrinsics.height}, {intrinsics.width})"
        )
    valid = np.isfinite(image) & (image > 0)
    v, u = np.nonzero(valid)
    z = image[v, u]
    points = np.empty((z.size, 3), dtype=np.float32)
    points[:, 0] = -(u - intrinsics.cx) * z / intrinsics.fx
    points[:, 1] = -(v - intrinsics.cy) * z / intrinsics.fy
    points[:, 2] = z
    return points


def voxel_downsample(points: npt.ArrayLike, voxel_m: float) -> npt.NDArray[np.float32]:
    """Average the points falling in each cubic voxel of edge ``voxel_m`` (numpy only).

    Args:
        points: (N, 3) points, any frame, metres.

    Returns:
        (M, 3) float32 voxel centroids, M ≤ N, in voxel-key order.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0 or voxel_m <= 0:
        return pts.astype(np.float32)
    keys = np.floor(pts / voxel_m).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, pts)
    result: npt.NDArray[np.float32] = (sums / counts[:, None]).astype(np.float32)
    return result
