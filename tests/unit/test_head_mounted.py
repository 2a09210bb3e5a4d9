"""The head-mounted sensor simulator (issue 15 item 5): report B's schedule, poses that agree
with the truth, the pose-to-frame mismatch and noise, mutual capture of the others."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skelfuse.agent.sim.head_mounted import (
    AXES,
    Axis,
    HeadRig,
    PoseErrors,
    head_turn_deg,
    noisy_pose,
    schedule_duration_s,
)
from skelfuse.agent.sim.kinect_model import KinectV2Params
from skelfuse.agent.sim.mutual import MutualCapture
from skelfuse.agent.sim.scenarios import RingWalkers
from skelfuse.protocol.sensor_pose import pose_matrix
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import apply

QUIET = KinectV2Params(
    jitter_base_m=0.0,
    jitter_per_m2=0.0,
    bias_trunk_m=0.0,
    bias_limb_m=0.0,
    bias_extremity_m=0.0,
    inferred_error_m=0.0,
    facing_bias=0.0,
    glitch_rate_hz=0.0,
    dropout_rate_hz=0.0,
)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    relative = a[:3, :3].T @ b[:3, :3]
    return math.degrees(math.acos(min(1.0, max(-1.0, (np.trace(relative) - 1.0) / 2.0))))


@pytest.mark.parametrize(
    ("t_s", "degrees"),
    [
        (0.0, 0.0),
        (0.99, 0.0),
        (1.5, 5.0),  # 10° left over the 2nd second
        (2.5, 10.0),
        (3.25, 5.0),  # 20° right over the 4th
        (4.0, -10.0),
        (4.5, -10.0),
        (5.5, -5.0),  # 10° left over the 6th
        (7.5, 0.0),  # still 3 s
        (9.0 + 1.5, 5.0),  # looped
    ],
)
def test_report_b_schedule(t_s: float, degrees: float) -> None:
    assert head_turn_deg(t_s) == pytest.approx(degrees, abs=1e-9)


def test_schedule_length_and_speed() -> None:
    assert schedule_duration_s() == 9.0
    # Five times faster: the 2nd second's turn happens over 0.2 s (50°/s).
    assert head_turn_deg(0.3, speed=5.0) == pytest.approx(5.0)
    with pytest.raises(ValueError, match="positive"):
        head_turn_deg(1.0, speed=0.0)


@pytest.mark.parametrize("axis", AXES)
def test_the_rig_turns_about_its_axis_through_the_neck(axis: Axis) -> None:
    rig = HeadRig(axis=axis, look_down_deg=0.0)
    neck = np.array([0.5, 1.5, -1.0])
    still, turned = rig.sensor_pose(neck, 0.0, 0.5), rig.sensor_pose(neck, 0.0, 2.5)
    assert _angle_deg(still, turned) == pytest.approx(10.0)
    # The sensor stays at its mount distance from the pivot.
    lever = np.linalg.norm(rig.mount_offset_m)
    assert np.linalg.norm(turned[:3, 3] - neck) == pytest.approx(lever)
    # Yaw turns about up, pitch about the head's left (+X), roll about forward (+Z).
    column = {"yaw": 1, "pitch": 0, "roll": 2}[axis]
    np.testing.assert_allclose(turned[:3, column], still[:3, column], atol=1e-12)
    if axis == "yaw":  # report B's "left" is +X of the head: the forward axis swings to +X
        assert turned[0, 2] > 0.1


@pytest.mark.parametrize("axis", AXES)
def test_a_noiseless_sensor_placed_with_its_own_poses_gives_the_truth(axis: Axis) -> None:
    capture = MutualCapture(
        RingWalkers(2, 1.25, walk_m=0.6),
        [HeadRig(axis=axis), HeadRig(axis=axis)],
        params=QUIET,
    )
    worst = 0.0
    for t in np.arange(0.0, 9.0, 0.25):
        for wearer in (0, 1):
            frame = capture.frame(wearer, float(t))
            assert [b.person for b in frame.bodies] == [1 - wearer]  # never its own wearer
            placed = apply(pose_matrix(frame.pose), frame.bodies[0].joints_m.astype(np.float64))
            truth = capture.truth(float(t))[1 - wearer]
            worst = max(worst, float(np.nanmax(np.linalg.norm(placed - truth, axis=1))))
    assert worst < 1e-5
    # The same joints with a held pose are far off: the head really moved.
    first = capture.sensor_pose(0, 0.0)
    turned = capture.sensor_pose(0, 2.5)
    assert _angle_deg(first, turned) > 9.0


def test_the_mismatch_attaches_the_pose_of_a_later_instant() -> None:
    # Person 1 stands: only the head turn moves wearer 0's sensor (10°/s during second 2).
    errors = PoseErrors(mismatch_ms=100.0)
    capture = MutualCapture(RingWalkers(2, 1.25), [HeadRig(axis="yaw")], errors=errors)
    frame = capture.frame(0, 1.5)
    reported = pose_matrix(frame.pose)
    assert _angle_deg(frame.true_pose, reported) == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(reported, capture.sensor_pose(0, 1.6), atol=1e-9)
    still = capture.frame(0, 0.5)  # the head is still: a late pose is the same pose
    assert _angle_deg(still.true_pose, pose_matrix(still.pose)) < 1e-6


def test_pose_noise_has_the_asked_spread() -> None:
    rng = np.random.default_rng(3)
    errors = PoseErrors(position_noise_mm=2.0, rotation_noise_deg=0.5)
    poses = [pose_matrix(noisy_pose(np.eye(4), errors, rng)) for _ in range(2000)]
    shifts = np.array([p[:3, 3] for p in poses]) * 1000.0
    assert np.std(shifts, axis=0) == pytest.approx([2.0] * 3, rel=0.1)
    angles = np.array([_angle_deg(np.eye(4), p) for p in poses])
    # Three axes of σ 0.5°: the angle's RMS is 0.5·√3.
    assert math.sqrt(float(np.mean(angles**2))) == pytest.approx(0.5 * math.sqrt(3), rel=0.1)


def test_ring_walkers_face_each_other() -> None:
    walkers = RingWalkers(3, 1.5, walk_m=0.6)
    for t in (0.0, 1.0, 2.7):
        joints = walkers.joints_at(t)
        for person in joints:
            left = person[JointId.SHOULDER_LEFT] - person[JointId.SHOULDER_RIGHT]
            forward = np.cross(left, [0.0, 1.0, 0.0])
            to_centre = -person[JointId.SPINE_BASE]
            to_centre[1] = 0.0
            cosine = forward @ to_centre / np.linalg.norm(forward) / np.linalg.norm(to_centre)
            assert cosine > 0.99
            radius = math.hypot(person[JointId.SPINE_BASE][0], person[JointId.SPINE_BASE][2])
            assert 1.5 - 0.31 < radius < 1.5 + 0.31
    with pytest.raises(ValueError, match="centre"):
        RingWalkers(2, 0.5, walk_m=1.0)
