"""The floor: a plane fit on a sensor's point cloud (or the Kinect's own floor plane), and the
levelling that gives the world frame +Y up with the floor at y = 0.

Plane convention: ``n·p + d = 0`` with ``n`` a unit normal pointing up (into the room, towards
the sensor's side), so ``n·p + d`` is the height of ``p`` above the floor and, for a plane in a
sensor's frame, ``d`` is the sensor's height. This matches the Kinect v2 SDK's
``FloorClipPlane`` (x, y, z, w).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.errors import DegenerateGeometry, InvalidInput, NotEnoughCorrespondences
from skelfuse.protocol.transform import Matrix4, invert

FloatArray = npt.NDArray[np.float64]

DEFAULT_INLIER_M: Final = 0.02
"""RANSAC inlier distance (metres): ~3σ of Kinect v2 depth noise at 2–3 m."""


@dataclass(frozen=True, slots=True)
class FloorFit:
    """A floor plane ``normal·p + d = 0`` in some sensor's frame.

    ``normal``: (3,) float64 unit vector pointing up; ``d``: metres (the frame origin's height
    above the floor); ``rmse_m``: RMS point-to-plane distance of the inliers (0 for a plane that
    was not fitted); ``inlier_count``: points on the plane (0 when not fitted).
    """

    normal: FloatArray
    d: float
    rmse_m: float
    inlier_count: int

    def height_of(self, points: npt.ArrayLike) -> FloatArray:
        """Signed height (metres) above the floor of (..., 3) points in the same frame."""
        pts = np.asarray(points, dtype=np.float64)
        heights: FloatArray = pts @ self.normal + self.d
        return heights


def _unit(vector: npt.ArrayLike, name: str) -> FloatArray:
    v = np.asarray(vector, dtype=np.float64).reshape(-1)
    norm = float(np.linalg.norm(v)) if v.shape == (3,) else 0.0
    if v.shape != (3,) or not np.isfinite(v).all() or norm < 1e-9:
        raise InvalidInput(f"{name}: expected a finite non-zero 3-vector, got {v.tolist()}")
    unit: FloatArray = v / norm
    return unit


def _plane_lsq(points: FloatArray, weights: FloatArray) -> tuple[FloatArray, float]:
    """Weighted total-least-squares plane through (N, 3) points: unit normal and offset d."""
    w = weights / weights.sum()
    centroid = (w[:, None] * points).sum(axis=0)
    _, _, vt = np.linalg.svd((points - centroid) * np.sqrt(w)[:, None], full_matrices=False)
    normal: FloatArray = vt[2]
    return normal, float(-normal @ centroid)


def fit_floor(
    points: npt.ArrayLike,
    up_hint: npt.ArrayLike = (0.0, 1.0, 0.0),
    *,
    max_tilt_deg: float = 30.0,
    inlier_m: float = DEFAULT_INLIER_M,
    iterations: int = 300,
    min_inliers: int = 200,
    noise_m: tuple[float, float] = (0.0015, 0.0015),
    rng: np.random.Generator | None = None,
) -> FloorFit:
    """Find the floor in a point cloud: the lowest large plane that is roughly horizontal.

    RANSAC draws planes through 3 points and keeps those whose normal is within
    ``max_tilt_deg`` of ``up_hint``. Among the planes with at least a third of the best
    plane's inliers (box tops, table tops and the floor, not a wall), the lowest along the up
    direction wins, and within 10 cm of it the one with the most inliers; then a least-squares
    refit over its inliers (4 rounds, band ``inlier_m + 3σ``), each point weighted by
    1/σ² with σ = ``noise_m[0] + noise_m[1]·r²`` and r its distance from the sensor (depth
    noise grows with range, so far floor points would otherwise tilt the plane).

    Args:
        points: (N, 3) cloud in one sensor's frame, metres (NaN rows are dropped).
        up_hint: (3,) roughly "up" in that frame; for a Kinect, its +Y (the default).
        max_tilt_deg: largest angle between the floor normal and ``up_hint``.
        inlier_m: RANSAC inlier distance.
        iterations: RANSAC hypotheses.
        min_inliers: fewest points the floor must have.
        noise_m: depth noise model (σ at 0 m, growth per m²) for the least-squares weights;
            (1, 0) weighs all points alike (for clouds not in a sensor frame).
        rng: random generator (default: seeded, so results are reproducible).

    Returns:
        :class:`FloorFit`, normal pointing to the ``up_hint`` side.

    Raises:
        InvalidInput: wrong shape, inf, or a zero ``up_hint``.
        NotEnoughCorrespondences: fewer than ``min_inliers`` points in the cloud.
        DegenerateGeometry: no horizontal-ish plane with ``min_inliers`` points.
    """
    raw = np.asarray(points, dtype=np.float64)
    if raw.ndim != 2 or raw.shape[1] != 3:
        raise InvalidInput(f"points: expected an (N, 3) cloud, got shape {raw.shape}")
    if np.isinf(raw).any():
        raise InvalidInput("points: the cloud contains inf values")
    pts = raw[np.isfinite(raw).all(axis=1)]
    up = _unit(up_hint, "up_hint")
    if len(pts) < min_inliers:
        raise NotEnoughCorrespondences(
            f"the cloud has {len(pts)} valid points, fewer than the {min_inliers} a floor needs; "
            "capture depth again with the floor in view"
        )
    generator = rng if rng is not None else np.random.default_rng(0)
    normals, offsets = _horizontal_planes(pts, up, generator, iterations, max_tilt_deg)
    normal, d = _lowest_large_plane(pts, normals, offsets, up, inlier_m, min_inliers)
    return _weighted_refit(pts, normal, d, up, inlier_m, noise_m, min_inliers)


def _horizontal_planes(
    pts: FloatArray,
    up: FloatArray,
    generator: np.random.Generator,
    iterations: int,
    max_tilt_deg: float,
) -> tuple[FloatArray, FloatArray]:
    """RANSAC hypotheses: planes through 3 random points of the (N, 3) cloud, kept if their
    normal is within ``max_tilt_deg`` of ``up``. Returns their (H, 3) unit normals (towards
    ``up``) and (H,) offsets d, metres.

    Raises:
        DegenerateGeometry: no such plane.
    """
    cos_max = float(np.cos(np.radians(max_tilt_deg)))
    samples = generator.integers(0, len(pts), size=(iterations, 3))
    a, b, c = pts[samples[:, 0]], pts[samples[:, 1]], pts[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    normals[ok] /= norms[ok, None]
    flip = normals @ up < 0
    normals[flip] *= -1
    ok &= normals @ up >= cos_max
    if not ok.any():
        raise DegenerateGeometry(
            f"no plane within {max_tilt_deg:.0f}° of the up direction {up.round(3).tolist()} "
            "in the cloud; is the sensor mounted upright with the floor in view?"
        )
    normals = normals[ok]
    offsets = -np.sum(normals * a[ok], axis=1)
    return normals, offsets


def _lowest_large_plane(
    pts: FloatArray,
    normals: FloatArray,
    offsets: FloatArray,
    up: FloatArray,
    inlier_m: float,
    min_inliers: int,
) -> tuple[FloatArray, float]:
    """Of the hypotheses with at least a third of the best one's inliers (and ``min_inliers``),
    the lowest along ``up``, and within 10 cm of it the one with the most inliers: its (3,)
    normal and offset d (metres).

    Raises:
        DegenerateGeometry: no hypothesis has ``min_inliers`` points.
    """
    # Inlier counts, in chunks to bound memory (hypotheses × points).
    counts = np.empty(len(normals), dtype=np.int64)
    for start in range(0, len(normals), 32):
        dist = np.abs(pts @ normals[start : start + 32].T + offsets[start : start + 32])
        counts[start : start + 32] = (dist < inlier_m).sum(axis=0)
    # Height of each plane along "up": the plane is where up·p = -d / (n·up).
    level = -offsets / (normals @ up)
    large = counts >= max(min_inliers, counts.max() / 3)
    if not large.any():
        raise DegenerateGeometry(
            f"the largest horizontal-ish plane has {int(counts.max())} points, fewer than "
            f"{min_inliers}; capture depth with more of the floor in view"
        )
    lowest = float(level[large].min())
    near_lowest = large & (level <= lowest + 0.10)
    best = int(np.argmax(np.where(near_lowest, counts, -1)))
    return normals[best], float(offsets[best])


def _weighted_refit(
    pts: FloatArray,
    normal: FloatArray,
    d: float,
    up: FloatArray,
    inlier_m: float,
    noise_m: tuple[float, float],
    min_inliers: int,
) -> FloorFit:
    """The plane ``normal·p + d = 0`` refitted by weighted least squares over its inliers
    (4 rounds; band and weights from the depth noise model, see :func:`fit_floor`).

    Raises:
        DegenerateGeometry: fewer than ``min_inliers`` points left on the refitted plane.
    """
    sigma = noise_m[0] + noise_m[1] * np.sum(pts**2, axis=1)
    weights = 1.0 / np.maximum(sigma, 1e-6) ** 2
    # A fixed band would hold the refit near a slightly tilted RANSAC plane (far, noisy points
    # outside the band are cut on one side); a band that widens with the depth noise does not.
    band = inlier_m + 3.0 * sigma
    for _ in range(4):
        inliers = np.abs(pts @ normal + d) < band
        if inliers.sum() < 3:
            break
        normal, d = _plane_lsq(pts[inliers], weights[inliers])
        if normal @ up < 0:
            normal, d = -normal, -d
    residual = pts @ normal + d
    inliers = np.abs(residual) < band
    count = int(inliers.sum())
    if count < min_inliers:
        raise DegenerateGeometry(
            f"the floor plane keeps only {count} points after refinement (< {min_inliers}); "
            "capture depth with more of the floor in view"
        )
    rmse = float(np.sqrt(np.mean(residual[inliers] ** 2)))
    return FloorFit(normal, d, rmse, count)


def floor_from_kinect_plane(a: float, b: float, c: float, d: float) -> FloorFit:
    """The Kinect v2 SDK's ``FloorClipPlane`` (x, y, z, w) as a :class:`FloorFit`.

    The SDK's (a, b, c) is the floor normal in the camera frame and d the sensor's height;
    (0, 0, 0, 0) means the SDK has not found the floor.

    Raises:
        InvalidInput: NaN/inf, or a zero normal (the SDK has no floor estimate yet).
    """
    values = np.array([a, b, c, d], dtype=np.float64)
    if not np.isfinite(values).all():
        raise InvalidInput(f"floor clip plane contains NaN/inf: {values.tolist()}")
    norm = float(np.linalg.norm(values[:3]))
    if norm < 1e-9:
        raise InvalidInput(
            "floor clip plane has a zero normal: the Kinect has not detected the floor yet; "
            "point the sensor so that more floor is visible, or use the depth-based floor fit"
        )
    return FloorFit(values[:3] / norm, float(values[3] / norm), 0.0, 0)


def level_to_floor(
    T_world_from_ref: npt.ArrayLike,
    floor_in_ref: FloorFit,
    *,
    centre_world: npt.ArrayLike | None = None,
    forward_ref: npt.ArrayLike = (0.0, 0.0, 1.0),
) -> Matrix4:
    """A new ``T_world_from_ref`` whose world has +Y up and the floor at y = 0.

    Everything calibrated in the old world frame follows with
    ``T_new_from_old = result @ invert(T_world_from_ref)``, applied to each sensor's pose.

    How the remaining three degrees of freedom (yaw and horizontal origin) are chosen:

    - yaw: the new world's +Z is the reference sensor's ``forward_ref`` direction (default its
      optical axis, +Z) projected onto the floor, so the reference sensor looks along +Z
      (``--pose`` yaw 0);
    - origin: on the floor directly below ``centre_world`` (a point in the *old* world frame,
      e.g. the centre of the capture area or of the walked path); default the reference sensor,
      which then stands at (0, height, 0).

    Args:
        T_world_from_ref: (4, 4) the reference sensor's pose in the current world frame.
        floor_in_ref: the floor plane in the reference sensor's frame.
        centre_world: (3,) point in the current world frame that the origin goes under.
        forward_ref: (3,) direction in the reference frame that becomes +Z after levelling.

    Raises:
        InvalidInput: non-rigid input, or a forward direction (nearly) perpendicular to the
            floor.
    """
    pose = np.asarray(T_world_from_ref, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise InvalidInput(f"T_world_from_ref must be a finite (4, 4) matrix, got {pose.shape}")
    up = _unit(floor_in_ref.normal, "floor normal")
    forward = _unit(forward_ref, "forward_ref")
    forward_flat = forward - (forward @ up) * up
    if np.linalg.norm(forward_flat) < 0.05:
        raise InvalidInput(
            "forward_ref is (nearly) perpendicular to the floor; pass a horizontal direction"
        )
    z_axis = forward_flat / np.linalg.norm(forward_flat)
    x_axis = np.cross(up, z_axis)
    rotation_new_from_ref = np.stack([x_axis, up, z_axis])  # rows: new axes in ref coordinates
    if centre_world is None:
        centre_ref = np.zeros(3)
    else:
        centre = np.asarray(centre_world, dtype=np.float64).reshape(3)
        centre_ref = invert(pose)[:3, :3] @ centre + invert(pose)[:3, 3]
    # Origin: the foot of the centre on the floor plane (ref frame).
    origin_ref = centre_ref - floor_in_ref.height_of(centre_ref) * up
    result = np.eye(4)
    result[:3, :3] = rotation_new_from_ref
    result[:3, 3] = -rotation_new_from_ref @ origin_ref
    return result


def floor_error(
    floor_in_sensor: FloorFit, T_world_from_sensor_true: npt.ArrayLike
) -> tuple[float, float]:
    """Tilt (degrees) and height error (millimetres) of a floor estimate, for benchmarks.

    The truth is the world floor (y = 0, +Y up) seen from the sensor's true pose. The tilt is
    the angle between the estimated and the true normal; the height error is the estimated
    minus the true sensor height.
    """
    pose = np.asarray(T_world_from_sensor_true, dtype=np.float64)
    true_up = pose[:3, :3].T @ np.array([0.0, 1.0, 0.0])
    cos = float(np.clip(floor_in_sensor.normal @ true_up, -1.0, 1.0))
    tilt = float(np.degrees(np.arccos(cos)))
    return tilt, (floor_in_sensor.d - float(pose[1, 3])) * 1000.0
