"""Moving sensors' poses: matrix round trips, slerp, and reading a pose track in time."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skelfuse.geometry.quaternion import (
    matrix_to_quaternion,
    quaternion_slerp,
    quaternion_to_matrix,
)
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import (
    PoseTrack,
    interpolate_pose,
    pose_from_matrix,
    pose_matrix,
)
from skelfuse.protocol.transform import axis_rotation, compose_rotations


def _yaw_pose(yaw_deg: float, x: float = 0.0) -> SensorPose:
    half = math.radians(yaw_deg) / 2
    return SensorPose((x, 1.6, 0.0), (0.0, math.sin(half), 0.0, math.cos(half)))


def test_quaternion_to_matrix_inverts_matrix_to_quaternion() -> None:
    rng = np.random.default_rng(3)
    rotations = np.stack(
        [
            compose_rotations("yxz", [float(a) for a in rng.uniform(-math.pi, math.pi, 3)])
            for _ in range(50)
        ]
    )
    back = quaternion_to_matrix(matrix_to_quaternion(rotations))
    np.testing.assert_allclose(back, rotations, atol=1e-12)


def test_quaternion_to_matrix_normalises_a_slightly_long_quaternion() -> None:
    matrix = quaternion_to_matrix(np.array([0.0, 0.0, 0.0, 1.0001]))
    np.testing.assert_allclose(matrix, np.eye(3), atol=1e-12)


def test_slerp_halfway_is_half_the_angle_and_takes_the_short_arc() -> None:
    a = matrix_to_quaternion(axis_rotation("y", 0.0))
    b = matrix_to_quaternion(axis_rotation("y", math.radians(80)))
    half = quaternion_slerp(a, b, 0.5)
    np.testing.assert_allclose(quaternion_to_matrix(half), axis_rotation("y", math.radians(40)))
    # -b is the same rotation: slerp must not go the long way round (through 220°).
    np.testing.assert_allclose(
        quaternion_to_matrix(quaternion_slerp(a, -b, 0.5)),
        axis_rotation("y", math.radians(40)),
        atol=1e-12,
    )


def test_slerp_of_nearly_equal_quaternions_is_finite() -> None:
    a = np.array([0.0, 0.0, 0.0, 1.0])
    b = np.array([1e-9, 0.0, 0.0, 1.0])
    q = quaternion_slerp(a, b, 0.3)
    assert np.isfinite(q).all()
    assert math.isclose(float(np.linalg.norm(q)), 1.0)


def test_pose_matrix_round_trip() -> None:
    pose = SensorPose((0.5, 1.7, -2.0), (0.1, 0.7, -0.2, 0.677))
    back = pose_from_matrix(pose_matrix(pose))
    np.testing.assert_allclose(back.position_m, pose.position_m)
    np.testing.assert_allclose(pose_matrix(back)[:3, :3], pose_matrix(pose)[:3, :3], atol=1e-12)
    assert back.rotation_xyzw[3] >= 0


def test_interpolate_pose_moves_position_linearly_and_yaw_by_slerp() -> None:
    middle = interpolate_pose(_yaw_pose(0, x=0.0), _yaw_pose(20, x=1.0), 0.25)
    assert middle.position_m == pytest.approx((0.25, 1.6, 0.0))
    np.testing.assert_allclose(
        pose_matrix(middle)[:3, :3], axis_rotation("y", math.radians(5)), atol=1e-12
    )


def test_pose_track_interpolates_holds_ends_and_refuses_gaps() -> None:
    track = PoseTrack(
        [0.0, 0.1, 1.0],
        [_yaw_pose(0, 0.0), _yaw_pose(10, 1.0), _yaw_pose(10, 2.0)],
        max_gap_s=0.25,
        max_extrapolation_s=0.05,
    )
    at = track.at(0.05)
    assert at is not None and at.position_m[0] == pytest.approx(0.5)
    assert track.at(0.5) is None  # inside the 0.9 s gap: the tracker lost the sensor
    assert track.at(-0.04) == track.poses[0]
    assert track.at(-0.06) is None
    assert track.at(1.04) == track.poses[-1]
    assert track.at(1.06) is None


@pytest.mark.parametrize(
    ("times", "count", "message"),
    [
        ([0.0, 0.0], 2, "increasing"),
        ([0.0, float("nan")], 2, "finite"),
        ([0.0], 2, "1 times for 2 poses"),
        ([], 0, "at least one"),
    ],
)
def test_pose_track_rejects_bad_times(times: list[float], count: int, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        PoseTrack(times, [_yaw_pose(0)] * count)
