"""Checks of single untrusted values at the wire's trust boundary (used by :mod:`protocol.wire`).

Each takes what msgpack produced from a peer's bytes and returns a plain, checked value, or
raises :class:`~protocol.errors.DecodeError` with the ``reason`` the server counts rejections by.
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.constants import MAX_COORDINATE_M
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState

UNIT_TOLERANCE: Final = 1e-3
"""How far from 1 a floor normal's or a sensor pose quaternion's length may be."""
UINT64_MAX: Final = 2**64 - 1
INT64_MAX: Final = 2**63 - 1
_JOINT_BYTES: Final = JOINT_COUNT * 3 * 4


def field_of(raw: dict[str, Any], name: str, kind: type | tuple[type, ...]) -> Any:
    """``raw[name]``, an instance of ``kind`` (a bool only where ``kind`` names bool).

    Raises:
        DecodeError: ``bad_field``, missing or of another type.
    """
    if name not in raw:
        raise DecodeError("bad_field", f"missing field {name!r} in {raw.get('type')!r} message")
    value = raw[name]
    # bool is an int subclass; a True where a number belongs is a bug on the other side.
    if isinstance(value, bool) and bool not in (kind if isinstance(kind, tuple) else (kind,)):
        raise DecodeError("bad_field", f"field {name!r} must be {kind}, got bool")
    if not isinstance(value, kind):
        raise DecodeError("bad_field", f"field {name!r} must be {kind}, got {type(value).__name__}")
    return value


def uint(raw: dict[str, Any], name: str, maximum: int = INT64_MAX) -> int:
    """``raw[name]``, an int in 0..``maximum``.

    Raises:
        DecodeError: ``bad_field`` (missing, not an int) or ``out_of_range``.
    """
    value: int = field_of(raw, name, int)
    if not 0 <= value <= maximum:
        raise DecodeError("out_of_range", f"field {name!r} = {value} out of range 0..{maximum}")
    return value


def finite_float(raw: dict[str, Any], name: str) -> float:
    """``raw[name]``, a finite int or float, as a float.

    Raises:
        DecodeError: ``bad_field`` (missing, not a number) or ``non_finite``.
    """
    value = float(field_of(raw, name, (int, float)))
    if not math.isfinite(value):
        raise DecodeError("non_finite", f"field {name!r} must be finite, got {value}")
    return value


def joint_arrays(
    joints_buf: bytes, states_buf: bytes, index: int
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """Body ``index``'s joints (25, 3) float32 metres and states (25,) uint8 from their bytes.

    NOT_TRACKED joints come back NaN; every other joint is finite and within
    ``MAX_COORDINATE_M`` of the sensor.

    Raises:
        DecodeError: ``bad_shape`` (byte counts), ``out_of_range`` (a state above TRACKED, a
            joint too far) or ``non_finite``.
    """
    if len(joints_buf) != _JOINT_BYTES:
        raise DecodeError(
            "bad_shape",
            f"body {index}: joints must be {_JOINT_BYTES} bytes (25×3 float32), "
            f"got {len(joints_buf)}",
        )
    if len(states_buf) != JOINT_COUNT:
        raise DecodeError(
            "bad_shape", f"body {index}: states must be 25 bytes, got {len(states_buf)}"
        )
    # Copy: frombuffer views are read-only and tied to the message buffer.
    joints = np.frombuffer(joints_buf, dtype="<f4").reshape(JOINT_COUNT, 3).astype(np.float32)
    states = np.frombuffer(states_buf, dtype=np.uint8).copy()
    if states.max() > TrackingState.TRACKED:
        raise DecodeError("out_of_range", f"body {index}: tracking state {states.max()} > 2")
    seen = states != TrackingState.NOT_TRACKED
    seen_joints = joints[seen]
    if not np.isfinite(seen_joints).all():
        raise DecodeError("non_finite", f"body {index}: NaN or infinity in a tracked joint")
    if np.isinf(joints).any():
        raise DecodeError("non_finite", f"body {index}: infinity in joints")
    if seen_joints.size and np.abs(seen_joints).max() > MAX_COORDINATE_M:
        raise DecodeError(
            "out_of_range", f"body {index}: a joint is more than {MAX_COORDINATE_M} m away"
        )
    # NOT_TRACKED positions carry no meaning; normalise them so nothing downstream uses them.
    joints[~seen] = np.nan
    return joints, states


def rigid_pose(matrix: list[Any]) -> npt.NDArray[np.float64]:
    """A pose hint's 16 numbers (row-major) as a (4, 4) float64 proper rigid transform.

    Raises:
        DecodeError: ``bad_shape`` (not 16 numbers), ``non_finite``, or ``bad_field`` (not a
            rotation and translation).
    """
    if len(matrix) != 16 or not all(
        isinstance(x, int | float) and not isinstance(x, bool) for x in matrix
    ):
        raise DecodeError("bad_shape", "pose_hint T_world_from_sensor must be 16 numbers")
    pose = np.asarray(matrix, dtype=np.float64).reshape(4, 4)
    if not np.isfinite(pose).all():
        raise DecodeError("non_finite", "pose_hint has NaN or infinity")
    rotation = pose[:3, :3]
    if np.abs(rotation).max() > 1.001:  # also keeps the products below from overflowing
        raise DecodeError("bad_field", "pose_hint is not a rigid transform")
    if (
        not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4)
        or not np.allclose(pose[3], [0, 0, 0, 1])
        or np.linalg.det(rotation) < 0
    ):
        raise DecodeError("bad_field", "pose_hint is not a rigid transform")
    return pose


def sensor_pose(value: object) -> SensorPose:
    """A frame's ``pose``: ``[px, py, pz, qx, qy, qz, qw]`` (metres; a unit quaternion).

    Raises:
        DecodeError: ``bad_shape`` (not 7 numbers), ``non_finite``, or ``out_of_range`` (the
            quaternion's length is not 1 within :data:`UNIT_TOLERANCE`).
    """
    if (
        (type(value) is not list and type(value) is not tuple)
        or len(value) != 7
        or not all(type(x) is float or type(x) is int for x in value)
    ):
        raise DecodeError("bad_shape", "frame pose must be 7 numbers [px, py, pz, qx, qy, qz, qw]")
    px, py, pz, qx, qy, qz, qw = (float(x) for x in value)
    if not all(math.isfinite(x) for x in (px, py, pz, qx, qy, qz, qw)):
        raise DecodeError("non_finite", "frame pose has NaN or infinity")
    norm = math.sqrt(sum((qx * qx, qy * qy, qz * qz, qw * qw)))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise DecodeError("out_of_range", f"frame pose quaternion must be unit, |q| = {norm}")
    return SensorPose((px, py, pz), (qx, qy, qz, qw))
