"""MediaPipe's 33 landmarks → the 25-joint model (protocol/mediapipe_pose.py), on the stored
landmarks of the real four-camera clip (tests/data/mono_landmarks.npz): no model needed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.geometry.pinhole import CV_TO_SENSOR, Intrinsics
from skelfuse.protocol.mediapipe_pose import (
    AT_MOST_INFERRED,
    LANDMARK_COUNT,
    Landmark,
    StatePolicy,
    body_from_landmarks,
    landmark_states,
    place_landmarks,
    to_kinect_v2,
)
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "mono_landmarks.npz"
CAMERAS = ("cam01", "cam02", "cam03", "cam04")
J = JointId


@pytest.fixture(scope="module")
def clip() -> dict[str, np.ndarray]:
    with np.load(FIXTURE) as data:
        return {key: data[key] for key in data.files}


def _frame(clip: dict[str, np.ndarray], cam: str, f: int) -> tuple[np.ndarray, ...]:
    return clip[f"{cam}_image_px"][f], clip[f"{cam}_world_m"][f], clip[f"{cam}_visibility"][f]


def _intrinsics(clip: dict[str, np.ndarray], cam: str) -> Intrinsics:
    width, height = (int(v) for v in clip[f"{cam}_size_wh"])
    return Intrinsics.from_fov(width, height, 50.0)


def test_fixture_keys_and_shapes(clip: dict[str, np.ndarray]) -> None:
    for cam in CAMERAS:
        assert clip[f"{cam}_image_px"].shape == (100, LANDMARK_COUNT, 3)
        assert clip[f"{cam}_world_m"].shape == (100, LANDMARK_COUNT, 3)
        assert clip[f"{cam}_visibility"].shape == (100, LANDMARK_COUNT)
        assert clip[f"{cam}_detected"].all()
        assert clip[f"{cam}_size_wh"][1] == 1920  # portrait


def test_every_frame_maps_to_a_standing_body_in_front_of_the_camera(
    clip: dict[str, np.ndarray],
) -> None:
    widths = []
    for cam in CAMERAS:
        k = _intrinsics(clip, cam)
        size = tuple(int(v) for v in clip[f"{cam}_size_wh"])
        for f in range(100):
            image, world, vis = _frame(clip, cam, f)
            body = body_from_landmarks(image, world, vis, size, k)  # type: ignore[arg-type]
            joints = body.joints_m.astype(np.float64)
            assert joints.shape == (JOINT_COUNT, 3) and body.joints_m.dtype == np.float32
            assert np.isfinite(joints).all()  # every landmark detected: no NotTracked joint
            # Sensor frame: +Y up, +Z forward. Head above hips above a foot, all in front.
            feet = min(joints[J.FOOT_LEFT, 1], joints[J.FOOT_RIGHT, 1])
            assert joints[J.HEAD, 1] - 0.25 > joints[J.SPINE_BASE, 1] > feet + 0.5, (cam, f)
            assert (joints[:, 2] > 1.0).all() and (joints[:, 2] < 6.0).all(), (cam, f)
            widths.append(np.linalg.norm(joints[J.SHOULDER_LEFT] - joints[J.SHOULDER_RIGHT]))
            assert body.placement.rms_px < 60.0, (cam, f, body.placement.rms_px)
    # Shoulder width: an adult's, though MediaPipe narrows it when the person turns side-on.
    assert 0.25 < np.median(widths) < 0.45 and min(widths) > 0.08


def test_placed_landmarks_reproject_onto_the_image(clip: dict[str, np.ndarray]) -> None:
    cam = "cam02"
    k = _intrinsics(clip, cam)
    errors = []
    for f in range(0, 100, 10):
        image, world, vis = _frame(clip, cam, f)
        for mode in ("pose", "translation"):
            points, _ = place_landmarks(image, world, vis, k, mode)  # type: ignore[arg-type]
            errors.append(np.linalg.norm(k.project(points) - image[:, :2], axis=1))
    # The body model's shape, not the placement, limits the fit: tens of pixels of 1920.
    assert np.median(errors) < 30.0


def test_axes_and_sides_follow_the_landmarks(clip: dict[str, np.ndarray]) -> None:
    _, world, vis = _frame(clip, "cam01", 0)
    states = landmark_states(vis)
    joints, _ = to_kinect_v2(world, states)  # hip-centred world landmarks, no placement
    lm = world.astype(np.float64)
    expect_left = CV_TO_SENSOR * lm[Landmark.LEFT_SHOULDER]
    np.testing.assert_allclose(joints[J.SHOULDER_LEFT], expect_left, rtol=1e-6)
    np.testing.assert_allclose(
        joints[J.SPINE_BASE],
        CV_TO_SENSOR * lm[[Landmark.LEFT_HIP, Landmark.RIGHT_HIP]].mean(0),
        atol=1e-6,
    )
    np.testing.assert_allclose(joints[J.SPINE_BASE], 0.0, atol=0.02)  # world origin: the hips
    # MediaPipe's y is down: in the sensor frame the head is up.
    assert lm[Landmark.NOSE, 1] < 0 and joints[J.HEAD, 1] > 0
    spine = joints[[J.SPINE_BASE, J.SPINE_MID, J.SPINE_SHOULDER, J.NECK, J.HEAD], 1]
    assert (np.diff(spine) > 0).all()  # up the trunk in order


def test_states_follow_visibility_and_synthesised_joints_are_capped(
    clip: dict[str, np.ndarray],
) -> None:
    tracked_counts = np.zeros(JOINT_COUNT, int)
    for cam in CAMERAS:
        for f in range(100):
            image, world, vis = _frame(clip, cam, f)
            states = landmark_states(vis, image, (1088, 1920))
            _, joint_states = to_kinect_v2(world, states)
            for joint in AT_MOST_INFERRED:
                assert joint_states[joint] <= TrackingState.INFERRED
            tracked_counts += joint_states == TrackingState.TRACKED
            low = vis < 0.5
            assert (states[low] == TrackingState.INFERRED).all()
            assert (states[~low] == TrackingState.TRACKED).all()
    assert tracked_counts[J.SHOULDER_LEFT] > 300 and tracked_counts[J.SPINE_MID] == 0
    # cam03 sees the right arm poorly in about 44 frames (visibility < 0.5): Inferred there.
    vis = clip["cam03_visibility"]
    occluded = vis[:, Landmark.RIGHT_ELBOW] < 0.5
    assert 30 < occluded.sum() < 60
    for f in np.flatnonzero(occluded):
        _, joint_states = to_kinect_v2(clip["cam03_world_m"][f], landmark_states(vis[f]))
        assert joint_states[J.ELBOW_RIGHT] == TrackingState.INFERRED


def test_state_policy_thresholds_edges_and_missing() -> None:
    vis = np.linspace(0.0, 1.0, LANDMARK_COUNT)
    vis[3] = np.nan
    image = np.full((LANDMARK_COUNT, 2), 100.0)
    image[10] = (-50.0, 100.0)  # left of the image
    states = landmark_states(vis, image, (640, 480), StatePolicy(0.8, 0.2, 10.0))
    assert states[3] == TrackingState.NOT_TRACKED
    assert (states[vis < 0.2] == TrackingState.NOT_TRACKED).all()
    assert states[32] == TrackingState.TRACKED and states[20] == TrackingState.INFERRED
    vis_all = np.ones(LANDMARK_COUNT)
    assert landmark_states(vis_all, image, (640, 480))[10] == TrackingState.INFERRED
    loose = StatePolicy(edge_margin_px=100.0)
    assert landmark_states(vis_all, image, (640, 480), loose)[10] == TrackingState.TRACKED
    with pytest.raises(ValueError, match="size_wh"):
        landmark_states(vis_all, image)


def test_a_not_tracked_landmark_leaves_its_joints_nan() -> None:
    points = np.zeros((LANDMARK_COUNT, 3)) + [0.0, 0.0, 2.0]
    states = np.full(LANDMARK_COUNT, TrackingState.TRACKED, np.uint8)
    states[Landmark.LEFT_EAR] = TrackingState.NOT_TRACKED
    joints, joint_states = to_kinect_v2(points, states)
    for joint in (J.HEAD, J.NECK):  # Head uses both ears, Neck uses Head
        assert joint_states[joint] == TrackingState.NOT_TRACKED and np.isnan(joints[joint]).all()
    assert joint_states[J.SPINE_SHOULDER] == TrackingState.TRACKED
    assert joint_states[J.SPINE_MID] == TrackingState.INFERRED
    with pytest.raises(ValueError, match="expected"):
        to_kinect_v2(points[:25], states)
