"""Invariants of the virtual performers and the Kinect v2 sensor model."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from skelfuse.agent.sim.kinect_model import KinectV2Params, SimulatedKinect
from skelfuse.agent.sim.performer import ProceduralPerformer, standing_pose
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState, bone_lengths
from skelfuse.protocol.transform import apply, look_at_pose, pose_from_position_yaw_pitch

J = JointId
QUIET = KinectV2Params(glitch_rate_hz=0.0, dropout_rate_hz=0.0)


def test_performer_is_a_deterministic_function_of_time() -> None:
    a, b = ProceduralPerformer(3), ProceduralPerformer(3)
    for t in (0.0, 12.345, 1.7e9 + 0.5):
        np.testing.assert_array_equal(a.joints_at(t), b.joints_at(t))


@pytest.mark.parametrize("persons", [1, 6])
def test_performer_bodies_are_rigid_and_on_the_floor(persons: int) -> None:
    performer = ProceduralPerformer(persons)
    frames = np.stack([performer.joints_at(t) for t in np.arange(0.0, 60.0, 0.1)])
    lengths = bone_lengths(frames)  # (T, P, 24)
    cv = lengths.std(axis=0) / lengths.mean(axis=0)
    assert cv.max() < 1e-9, "procedural bones must keep their length"
    feet = frames[:, :, [J.FOOT_LEFT, J.FOOT_RIGHT], 1].min(axis=2)
    assert feet.min() > -1e-9 and feet.max() < 0.3
    assert frames[..., 1].max() < 2.3  # hands above the head at most


def test_performer_rejects_bad_counts() -> None:
    with pytest.raises(ValueError, match=r"1\.\.6"):
        ProceduralPerformer(7)


def front_sensor(distance: float = 2.5, params: KinectV2Params = QUIET) -> SimulatedKinect:
    return SimulatedKinect(look_at_pose((0.0, 1.0, distance), (0.0, 1.0, 0.0)), params, seed=3)


def facing(body: np.ndarray, heading: float) -> np.ndarray:
    """Rotate a standing body (facing +Z) to face ``heading`` (0 = +Z, π = -Z)."""
    c, s = math.cos(heading), math.sin(heading)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    centre = body[J.SPINE_BASE] * [1, 0, 1]
    return (body - centre) @ rot.T + centre


def standing_body() -> np.ndarray:
    return standing_pose()


def test_frontal_person_is_tracked_and_close_to_truth() -> None:
    kinect = front_sensor()
    body = standing_body()  # faces +Z, i.e. towards the sensor at z = 2.5
    errors = []
    for step in range(30):
        observation = kinect.observe(body[None], step / 30)[0]
        assert not observation.mirrored
        world = apply(kinect.T_world_from_sensor, observation.joints_m)
        errors.append(np.linalg.norm(world - body, axis=1).mean())
        assert (observation.states == TrackingState.TRACKED).mean() > 0.8
    assert 0.005 < np.mean(errors) < 0.08


def test_person_outside_the_field_of_view_is_not_reported() -> None:
    kinect = front_sensor()
    body = standing_body() + [5.0, 0.0, 0.0]  # far to the side
    assert kinect.observe(body[None], 0.0) == []
    behind = standing_body() + [0.0, 0.0, 6.0]  # behind the sensor
    assert kinect.observe(behind[None], 0.0) == []


def test_person_beyond_range_is_not_reported() -> None:
    kinect = front_sensor(distance=5.5)
    assert kinect.observe(standing_body()[None], 0.0) == []


def test_close_person_has_clipped_joints_not_tracked() -> None:
    kinect = SimulatedKinect(look_at_pose((0.0, 1.0, 1.3), (0.0, 1.0, 0.0)), QUIET, seed=1)
    observation = kinect.observe(standing_body()[None], 0.0)[0]
    clipped = observation.states == TrackingState.NOT_TRACKED
    assert clipped[[J.FOOT_LEFT, J.FOOT_RIGHT]].all(), "feet leave a 60° view at 1.3 m"
    assert np.isnan(observation.joints_m[clipped]).all()
    assert not clipped[J.SPINE_MID]


def test_jitter_grows_with_depth() -> None:
    params = replace(QUIET, bias_trunk_m=0.0, bias_limb_m=0.0, bias_extremity_m=0.0,
                     facing_bias=0.0)  # fmt: skip
    spreads = []
    for distance in (1.6, 4.0):
        kinect = front_sensor(distance, params)
        body = standing_body()
        samples = np.stack([kinect.observe(body[None], i / 30)[0].joints_m[J.SPINE_MID]
                            for i in range(300)])  # fmt: skip
        spreads.append(samples.std(axis=0).mean())
    assert spreads[1] > 2.5 * spreads[0]


def test_person_facing_away_is_mirrored() -> None:
    kinect = front_sensor()
    body = facing(standing_body(), math.pi)  # back to the sensor
    body[J.HAND_LEFT] += [0.0, 0.6, 0.0]  # raise the left hand to tell the sides apart
    observation = kinect.observe(body[None], 0.0)[0]
    assert observation.mirrored
    world = apply(kinect.T_world_from_sensor, observation.joints_m)
    # The joint labelled HandRight is where the true left hand is.
    assert np.linalg.norm(world[J.HAND_RIGHT] - body[J.HAND_LEFT]) < 0.15
    assert np.linalg.norm(world[J.HAND_LEFT] - body[J.HAND_LEFT]) > 0.4


def test_facing_bias_turns_the_body_towards_the_sensor() -> None:
    no_drift = replace(QUIET, facing_bias=0.5, bias_trunk_m=0.0, bias_limb_m=0.0,
                       bias_extremity_m=0.0)  # fmt: skip
    kinect = front_sensor(params=no_drift)
    body = facing(standing_body(), math.radians(60.0))
    reports = [kinect.observe(body[None], i / 30)[0].joints_m for i in range(60)]
    world = apply(kinect.T_world_from_sensor, np.mean(reports, axis=0))
    shoulders = world[J.SHOULDER_LEFT] - world[J.SHOULDER_RIGHT]
    reported = math.degrees(math.atan2(-shoulders[2], shoulders[0]))
    assert reported == pytest.approx(30.0, abs=2.0)


def test_joint_behind_another_person_is_inferred() -> None:
    kinect = front_sensor(distance=3.5)
    back = standing_body()
    front = standing_body() + [0.0, 0.0, 1.0]  # between the sensor and the other person
    observations = {o.person: o for o in kinect.observe(np.stack([back, front]), 0.0)}
    hidden = observations[0].states == TrackingState.INFERRED
    assert hidden[[J.SPINE_MID, J.SPINE_BASE]].all()
    assert (observations[1].states == TrackingState.TRACKED).mean() > 0.8


def test_body_reacquired_gets_new_tracking_id() -> None:
    kinect = front_sensor()
    body = standing_body()
    first = kinect.observe(body[None], 0.0)[0].tracking_id
    assert kinect.observe((body + [9.0, 0, 0])[None], 0.1) == []
    assert kinect.observe(body[None], 0.2)[0].tracking_id != first


def test_floor_plane_matches_world_floor() -> None:
    kinect = SimulatedKinect(pose_from_position_yaw_pitch((1.0, 1.4, 2.0), 200.0, 12.0), QUIET)
    a, b, c, d = kinect.floor_plane()
    floor_points_world = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, -2.0], [-3.0, 0.0, 1.0]])
    sensor_points = apply(np.linalg.inv(kinect.T_world_from_sensor), floor_points_world)
    np.testing.assert_allclose(sensor_points @ [a, b, c] + d, 0.0, atol=1e-9)
    assert d == pytest.approx(1.4)


def test_same_seed_same_observations() -> None:
    body = standing_body()[None]
    runs = []
    for _ in range(2):
        kinect = front_sensor(params=KinectV2Params())
        runs.append([kinect.observe(body, i / 30) for i in range(50)])
    for a, b in zip(*runs, strict=True):
        assert [o.tracking_id for o in a] == [o.tracking_id for o in b]
        for oa, ob in zip(a, b, strict=True):
            np.testing.assert_array_equal(oa.joints_m, ob.joints_m)
    assert runs[0][0][0].joints_m.shape[0] == JOINT_COUNT
