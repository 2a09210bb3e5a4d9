"""Unit quaternions ``(x, y, z, w)`` (Hamilton convention, active rotations: ``v' = q v q*``).

The feed's joint rotations and the wire's sensor poses are in this form (docs/api.md,
"Rotations"); these are the few operations the layers, apps and tests need, vectorised over any
leading dimensions.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def matrix_to_quaternion(rotations: F64) -> F64:
    """Rotation matrices (..., 3, 3) → unit quaternions (..., 4) ``(x, y, z, w)`` with w ≥ 0.

    Shepperd's method: each quaternion from the largest of its four squared components, so no
    division by a small number.
    """
    m = np.asarray(rotations, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    candidates = np.stack(
        [
            np.stack(
                [
                    1 + m00 - m11 - m22,
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 2, 1] - m[..., 1, 2],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    m[..., 0, 1] + m[..., 1, 0],
                    1 - m00 + m11 - m22,
                    m[..., 1, 2] + m[..., 2, 1],
                    m[..., 0, 2] - m[..., 2, 0],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1 - m00 - m11 + m22,
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                axis=-1,
            ),
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                    1 + trace,
                ],
                axis=-1,
            ),
        ],
        axis=-2,
    )  # fmt: skip  (..., 4 candidates, 4): candidate k is 4·q_k·q
    best = np.argmax(np.stack([m00, m11, m22, trace], axis=-1), axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    result: F64 = np.where(q[..., 3:] < 0, -q, q)
    return result


def quaternion_multiply(a: F64, b: F64) -> F64:
    """Hamilton products ``a · b`` of quaternions (..., 4) ``(x, y, z, w)``."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quaternion_rotate(q: F64, v: F64) -> F64:
    """Vectors (..., 3) rotated by unit quaternions (..., 4) ``(x, y, z, w)``: ``q v q*``."""
    q = np.asarray(q, dtype=np.float64)
    u, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(u, v)
    rotated: F64 = v + w * t + np.cross(u, t)
    return rotated


def quaternion_to_matrix(quaternions: F64) -> F64:
    """Unit quaternions (..., 4) ``(x, y, z, w)`` → rotation matrices (..., 3, 3).

    The input is normalised first, so a quaternion a little off unit length (as sent over the
    wire, within the protocol's tolerance) still gives a proper rotation.
    """
    q = np.asarray(quaternions, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def quaternion_slerp(a: F64, b: F64, alpha: npt.ArrayLike) -> F64:
    """Spherical interpolation from unit quaternions ``a`` to ``b`` (..., 4) at ``alpha`` (...).

    Takes the shorter arc (``b`` is negated where ``a · b < 0``: q and −q are the same rotation);
    nearly equal quaternions fall back to normalised linear interpolation, where slerp's
    ``sin θ`` division loses precision. ``alpha`` outside [0, 1] extrapolates along the arc.
    """
    qa = np.asarray(a, dtype=np.float64)
    qb = np.asarray(b, dtype=np.float64)
    t = np.asarray(alpha, dtype=np.float64)[..., None]
    dot = np.sum(qa * qb, axis=-1, keepdims=True)
    qb = np.where(dot < 0, -qb, qb)
    dot = np.clip(np.abs(dot), 0.0, 1.0)
    theta = np.arccos(dot)
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-6
    safe = np.where(near, 1.0, sin_theta)
    weight_a = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    weight_b = np.where(near, t, np.sin(t * theta) / safe)
    q = weight_a * qa + weight_b * qb
    result: F64 = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return result
