"""Rigid transforms as 4×4 float64 matrices, and the 3×3 rotations they are built from.

Naming: ``T_b_from_a`` maps points expressed in frame ``a`` into frame ``b``
(``p_b = T_b_from_a @ p_a``), so compositions read right to left.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

Matrix4 = npt.NDArray[np.float64]
FloatArray = npt.NDArray[np.float64]


def pose_from_position_yaw_pitch(
    position_m: tuple[float, float, float], yaw_deg: float, pitch_deg: float = 0.0
) -> Matrix4:
    """``T_world_from_sensor`` of a sensor placed in the room.

    World: right-handed, +Y up, metres, floor at y = 0. Sensor frame (Kinect v2 camera space):
    +X sensor-left, +Y up, +Z forward. Yaw is a right-handed turn about world +Y (yaw 0 looks
    along +Z, yaw 90 along +X); positive pitch tilts the sensor down.
    """
    yaw = np.radians(yaw_deg)
    pitch = np.radians(pitch_deg)
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    rot_yaw = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    # About the sensor's +X (its left): +pitch sends the forward axis (0, 0, 1) to (0, -sin, cos).
    rot_pitch = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    transform = np.eye(4)
    transform[:3, :3] = rot_yaw @ rot_pitch
    transform[:3, 3] = position_m
    return transform


def look_at_pose(
    position_m: tuple[float, float, float], target_m: tuple[float, float, float]
) -> Matrix4:
    """``T_world_from_sensor`` for a level-rolled sensor at ``position_m`` aimed at ``target_m``."""
    direction = np.asarray(target_m, dtype=np.float64) - np.asarray(position_m, dtype=np.float64)
    horizontal = float(np.hypot(direction[0], direction[2]))
    yaw = float(np.degrees(np.arctan2(direction[0], direction[2])))
    pitch = float(np.degrees(np.arctan2(-direction[1], horizontal)))
    return pose_from_position_yaw_pitch(position_m, yaw, pitch)


def invert(transform: Matrix4) -> Matrix4:
    """Inverse of a rigid transform (exact, no general matrix inverse)."""
    rotation = transform[:3, :3]
    inverse = np.eye(4)
    inverse[:3, :3] = rotation.T
    inverse[:3, 3] = -rotation.T @ transform[:3, 3]
    return inverse


def apply(transform: Matrix4, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Apply ``transform`` to (..., 3) points; NaN stays NaN.

    Each output coordinate is ``((x·r₀ + y·r₁) + z·r₂) + t`` with ``r`` its row of the rotation,
    element-wise, as the fusion step's compiled interpolation computes it
    (:mod:`skelfuse.fusion.world_views`); a BLAS product's floats depend on its kernel (fused
    multiply-adds or not, in its order).
    """
    pts = np.asarray(points, dtype=np.float64)
    rotation, shift = transform[:3, :3], transform[:3, 3]
    out: npt.NDArray[np.float64] = (
        (pts[..., 0:1] * rotation[:, 0] + pts[..., 1:2] * rotation[:, 1])
        + pts[..., 2:3] * rotation[:, 2]
        + shift
    )
    return out


def is_rigid(transform: npt.ArrayLike, atol: float = 1e-6) -> bool:
    """True when ``transform`` is a 4×4 proper rigid transform (rotation + translation)."""
    matrix = np.asarray(transform, dtype=np.float64)
    if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
        return False
    rotation = matrix[:3, :3]
    if np.abs(rotation).max() > 1.0 + atol:  # no rotation has such an entry; and R @ R.T of
        return False  # 1e200s would overflow (a warning) before the answer is known
    return bool(
        np.allclose(rotation @ rotation.T, np.eye(3), atol=atol)
        and np.linalg.det(rotation) > 0
        and np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=atol)
    )


# --- rotations (3×3) ----------------------------------------------------------------------------


def axis_rotation(axis: str, angle_rad: npt.ArrayLike) -> FloatArray:
    """(..., 3, 3) right-handed rotations by ``angle_rad`` (shape ...) about ``axis`` (x, y or z).

    Raises:
        KeyError: ``axis`` is not one of "x", "y", "z".
    """
    c = np.cos(angle_rad)
    s = np.sin(angle_rad)
    out = np.zeros((*np.shape(angle_rad), 3, 3))
    a, b = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    k = 3 - a - b
    out[..., k, k] = 1.0
    out[..., a, a] = c
    out[..., a, b] = -s
    out[..., b, a] = s
    out[..., b, b] = c
    return out


def compose_rotations(axes: Sequence[str], angles_rad: Sequence[npt.ArrayLike]) -> FloatArray:
    """The product R(axes[0])·R(axes[1])·… of axis rotations, broadcast over the angle arrays.

    ``axes`` "zyx" with angles (a, b, c) gives Rz(a)·Ry(b)·Rx(c): the last factor acts first on
    a vector. No axes gives the (3, 3) identity.
    """
    result: FloatArray | None = None
    for axis, angle in zip(axes, angles_rad, strict=True):
        rotation = axis_rotation(axis, angle)
        result = rotation if result is None else result @ rotation
    if result is None:
        return np.eye(3)
    return result


def kabsch_rotation(src: FloatArray, dst: FloatArray) -> FloatArray:
    """The proper rotation R (3, 3) minimising Σ‖R·src_i − dst_i‖² (Kabsch).

    Args:
        src: (N, 3) vectors; centre (and weight, by √w) them first for a fit between points.
        dst: (N, 3) corresponding vectors.

    Never a reflection: when the best orthogonal fit has det −1, the axis of least variance is
    flipped. Degenerate input (fewer than two independent vectors) gives one of the rotations
    that fit equally well; callers that need a unique answer check the spread first.
    """
    h = src.T @ dst  # cross-covariance (3, 3)
    u, _, vt = np.linalg.svd(h)
    fix = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(vt.T @ u.T)) or 1.0)])
    rotation: FloatArray = vt.T @ fix @ u.T
    return rotation
