"""Skeleton model (protocol/skeleton.py) and rigid-transform helpers (protocol/transform.py)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pytest

from skelfuse.protocol.skeleton import (
    AZURE_CONFIDENCE_TO_STATE,
    AZURE_JOINT_COUNT,
    AZURE_TO_KINECT_V2,
    BONES,
    CHILDREN,
    CMU_ASF_TO_KINECT_V2,
    CMU_BVH_TO_KINECT_V2,
    JOINT_COUNT,
    JOINT_NAMES,
    MIRROR_PERMUTATION,
    PARENTS,
    SKELETON_NAME,
    JointId,
    TrackingState,
    azure_to_kinect_v2,
    bone_lengths,
    skeleton_definition,
)
from skelfuse.protocol.transform import (
    apply,
    invert,
    is_rigid,
    look_at_pose,
    pose_from_position_yaw_pitch,
)

# Kinect for Windows SDK 2.0 JointType names, by value (shared/conventions.md §1.1).
SDK_JOINT_NAMES = (
    "SpineBase",
    "SpineMid",
    "Neck",
    "Head",
    "ShoulderLeft",
    "ElbowLeft",
    "WristLeft",
    "HandLeft",
    "ShoulderRight",
    "ElbowRight",
    "WristRight",
    "HandRight",
    "HipLeft",
    "KneeLeft",
    "AnkleLeft",
    "FootLeft",
    "HipRight",
    "KneeRight",
    "AnkleRight",
    "FootRight",
    "SpineShoulder",
    "HandTipLeft",
    "ThumbLeft",
    "HandTipRight",
    "ThumbRight",
)

# k4abt_joint_id_t names, by value (shared/conventions.md §1.2).
K4ABT_JOINT_NAMES = (
    "PELVIS",
    "SPINE_NAVEL",
    "SPINE_CHEST",
    "NECK",
    "CLAVICLE_LEFT",
    "SHOULDER_LEFT",
    "ELBOW_LEFT",
    "WRIST_LEFT",
    "HAND_LEFT",
    "HANDTIP_LEFT",
    "THUMB_LEFT",
    "CLAVICLE_RIGHT",
    "SHOULDER_RIGHT",
    "ELBOW_RIGHT",
    "WRIST_RIGHT",
    "HAND_RIGHT",
    "HANDTIP_RIGHT",
    "THUMB_RIGHT",
    "HIP_LEFT",
    "KNEE_LEFT",
    "ANKLE_LEFT",
    "FOOT_LEFT",
    "HIP_RIGHT",
    "KNEE_RIGHT",
    "ANKLE_RIGHT",
    "FOOT_RIGHT",
    "HEAD",
    "NOSE",
    "EYE_LEFT",
    "EAR_LEFT",
    "EYE_RIGHT",
    "EAR_RIGHT",
)

# The Kinect v2 joint each k4abt joint must land on (Kinect name -> k4abt name).
EXPECTED_AZURE_SOURCES = {
    "SpineBase": "PELVIS",
    "SpineMid": "SPINE_NAVEL",
    "Neck": "NECK",
    "Head": "HEAD",
    "SpineShoulder": "SPINE_CHEST",
    "ShoulderLeft": "SHOULDER_LEFT",
    "ElbowLeft": "ELBOW_LEFT",
    "WristLeft": "WRIST_LEFT",
    "HandLeft": "HAND_LEFT",
    "HandTipLeft": "HANDTIP_LEFT",
    "ThumbLeft": "THUMB_LEFT",
    "ShoulderRight": "SHOULDER_RIGHT",
    "ElbowRight": "ELBOW_RIGHT",
    "WristRight": "WRIST_RIGHT",
    "HandRight": "HAND_RIGHT",
    "HandTipRight": "HANDTIP_RIGHT",
    "ThumbRight": "THUMB_RIGHT",
    "HipLeft": "HIP_LEFT",
    "KneeLeft": "KNEE_LEFT",
    "AnkleLeft": "ANKLE_LEFT",
    "FootLeft": "FOOT_LEFT",
    "HipRight": "HIP_RIGHT",
    "KneeRight": "KNEE_RIGHT",
    "AnkleRight": "ANKLE_RIGHT",
    "FootRight": "FOOT_RIGHT",
}


# --- the joint set ---------------------------------------------------------------------------


def test_25_joints() -> None:
    assert JOINT_COUNT == 25
    assert len(JointId) == 25
    assert [int(j) for j in JointId] == list(range(25))
    assert len(JOINT_NAMES) == 25
    assert len(PARENTS) == 25
    assert len(MIRROR_PERMUTATION) == 25
    assert SKELETON_NAME == "kinect_v2_25"


def test_joint_names_are_spelled_like_the_sdk() -> None:
    assert JOINT_NAMES == SDK_JOINT_NAMES
    assert JOINT_NAMES[JointId.SPINE_BASE] == "SpineBase"
    assert JOINT_NAMES[JointId.HAND_TIP_LEFT] == "HandTipLeft"
    assert JOINT_NAMES[JointId.SPINE_SHOULDER] == "SpineShoulder"


def test_tracking_states() -> None:
    assert [(s.name, int(s)) for s in TrackingState] == [
        ("NOT_TRACKED", 0),
        ("INFERRED", 1),
        ("TRACKED", 2),
    ]


def test_parents_match_the_published_array() -> None:
    expected = (
        -1,
        0,
        20,
        2,
        20,
        4,
        5,
        6,
        20,
        8,
        9,
        10,
        0,
        12,
        13,
        14,
        0,
        16,
        17,
        18,
        1,
        7,
        6,
        11,
        10,
    )
    assert expected == PARENTS


def test_parents_form_a_tree_rooted_at_spine_base() -> None:
    roots = [j for j, p in enumerate(PARENTS) if p < 0]
    assert roots == [JointId.SPINE_BASE]
    assert all(-1 <= p < JOINT_COUNT for p in PARENTS)
    for joint in range(JOINT_COUNT):
        seen: set[int] = set()
        node = joint
        while PARENTS[node] >= 0:
            assert node not in seen, f"cycle through joint {JOINT_NAMES[node]}"
            seen.add(node)
            node = PARENTS[node]
        assert node == JointId.SPINE_BASE, f"{JOINT_NAMES[joint]} does not reach SpineBase"
        assert len(seen) < JOINT_COUNT


def test_parents_are_anatomical() -> None:
    named = {JOINT_NAMES[c]: JOINT_NAMES[p] for c, p in enumerate(PARENTS) if p >= 0}
    assert named["Head"] == "Neck"
    assert named["Neck"] == "SpineShoulder"
    assert named["SpineShoulder"] == "SpineMid"
    assert named["SpineMid"] == "SpineBase"
    for side in ("Left", "Right"):
        assert named[f"Shoulder{side}"] == "SpineShoulder"
        assert named[f"Elbow{side}"] == f"Shoulder{side}"
        assert named[f"Wrist{side}"] == f"Elbow{side}"
        assert named[f"Hand{side}"] == f"Wrist{side}"
        assert named[f"HandTip{side}"] == f"Hand{side}"
        assert named[f"Thumb{side}"] == f"Wrist{side}"
        assert named[f"Hip{side}"] == "SpineBase"
        assert named[f"Knee{side}"] == f"Hip{side}"
        assert named[f"Ankle{side}"] == f"Knee{side}"
        assert named[f"Foot{side}"] == f"Ankle{side}"


def test_bones() -> None:
    assert len(BONES) == 24
    assert len(set(BONES)) == 24
    children = sorted(child for _, child in BONES)
    assert children == [j for j in range(JOINT_COUNT) if j != JointId.SPINE_BASE]
    for parent, child in BONES:
        assert PARENTS[child] == parent


def test_mirror_permutation_is_an_involution() -> None:
    perm = np.array(MIRROR_PERMUTATION)
    assert sorted(MIRROR_PERMUTATION) == list(range(JOINT_COUNT))
    np.testing.assert_array_equal(perm[perm], np.arange(JOINT_COUNT))


def test_mirror_permutation_swaps_exactly_the_ten_left_right_pairs() -> None:
    moved = [j for j in range(JOINT_COUNT) if MIRROR_PERMUTATION[j] != j]
    assert len(moved) == 20
    for joint in moved:
        name, partner = JOINT_NAMES[joint], JOINT_NAMES[MIRROR_PERMUTATION[joint]]
        if name.endswith("Left"):
            assert partner == name.removesuffix("Left") + "Right"
        else:
            assert name.endswith("Right")
            assert partner == name.removesuffix("Right") + "Left"
    for joint in range(JOINT_COUNT):
        if MIRROR_PERMUTATION[joint] == joint:
            assert not JOINT_NAMES[joint].endswith(("Left", "Right"))
    fixed = {JOINT_NAMES[j] for j in range(JOINT_COUNT) if MIRROR_PERMUTATION[j] == j}
    assert fixed == {"SpineBase", "SpineMid", "Neck", "Head", "SpineShoulder"}


def test_mirroring_keeps_the_tree() -> None:
    # A mirrored skeleton has the same bones: parent(mirror(j)) == mirror(parent(j)).
    for joint, parent in enumerate(PARENTS):
        if parent >= 0:
            assert PARENTS[MIRROR_PERMUTATION[joint]] == MIRROR_PERMUTATION[parent]


def test_children_invert_parents() -> None:
    assert [(p, c) for p, kids in enumerate(CHILDREN) for c in kids] == sorted(BONES)
    assert CHILDREN[JointId.SPINE_BASE] == (JointId.SPINE_MID, JointId.HIP_LEFT, JointId.HIP_RIGHT)
    assert CHILDREN[JointId.HEAD] == ()


@pytest.mark.parametrize("recipe", [CMU_ASF_TO_KINECT_V2, CMU_BVH_TO_KINECT_V2])
def test_cmu_maps_cover_every_joint_and_mirror_left_onto_right(recipe: object) -> None:
    assert isinstance(recipe, Mapping) and sorted(recipe) == list(JointId)
    for joint in JointId:
        weights = [w for _, w in recipe[joint]]
        assert sum(weights) == pytest.approx(1.0), joint.name
    for left, right in ((JointId.HAND_TIP_LEFT, JointId.HAND_TIP_RIGHT),
                        (JointId.KNEE_LEFT, JointId.KNEE_RIGHT)):  # fmt: skip
        assert MIRROR_PERMUTATION[left] == right
        (left_point, _), (right_point, _) = recipe[left][0], recipe[right][0]
        assert left_point[0] in "lL" and right_point[0] in "rR"
    assert CMU_BVH_TO_KINECT_V2[JointId.HAND_TIP_RIGHT] == (("RFingers.end", 1.0),)
    assert CMU_ASF_TO_KINECT_V2[JointId.KNEE_RIGHT] == (("rfemur", 1.0),)


def test_skeleton_definition() -> None:
    definition = skeleton_definition()
    assert definition["name"] == "kinect_v2_25"
    assert definition["joints"] == list(SDK_JOINT_NAMES)
    assert definition["parents"] == list(PARENTS)
    assert definition["bones"] == [list(b) for b in BONES]
    assert definition["units"] == "m"
    assert definition["up"] == "+y"
    assert definition["tracking_states"] == {"NOT_TRACKED": 0, "INFERRED": 1, "TRACKED": 2}


# --- Azure Kinect / Femto -----------------------------------------------------------------------


def test_azure_mapping_table() -> None:
    assert len(AZURE_TO_KINECT_V2) == JOINT_COUNT
    assert len(set(AZURE_TO_KINECT_V2)) == JOINT_COUNT
    assert all(0 <= k < AZURE_JOINT_COUNT for k in AZURE_TO_KINECT_V2)
    mapped = {JOINT_NAMES[i]: K4ABT_JOINT_NAMES[k] for i, k in enumerate(AZURE_TO_KINECT_V2)}
    assert mapped == EXPECTED_AZURE_SOURCES
    dropped = {K4ABT_JOINT_NAMES[k] for k in range(32)} - set(mapped.values())
    assert dropped == {
        "CLAVICLE_LEFT",
        "CLAVICLE_RIGHT",
        "NOSE",
        "EYE_LEFT",
        "EAR_LEFT",
        "EYE_RIGHT",
        "EAR_RIGHT",
    }


def test_azure_confidence_table() -> None:
    assert tuple(int(s) for s in AZURE_CONFIDENCE_TO_STATE) == (0, 1, 2, 2)


def _azure_body() -> tuple[np.ndarray, np.ndarray]:
    joints = np.arange(AZURE_JOINT_COUNT * 3, dtype=np.float64).reshape(32, 3) * 10.0 + 5.0
    levels = np.full(AZURE_JOINT_COUNT, 2, dtype=np.int32)
    return joints, levels


def test_azure_units_and_axes() -> None:
    joints, levels = _azure_body()
    pelvis = AZURE_TO_KINECT_V2[JointId.SPINE_BASE]
    joints[pelvis] = (100.0, -200.0, 1500.0)  # mm, +X right, +Y down
    out, states = azure_to_kinect_v2(joints, levels)
    assert out.shape == (25, 3)
    assert out.dtype == np.float32
    assert states.shape == (25,)
    assert states.dtype == np.uint8
    np.testing.assert_allclose(out[JointId.SPINE_BASE], (-0.1, 0.2, 1.5), rtol=1e-6)


def test_azure_selects_the_right_joints() -> None:
    joints, levels = _azure_body()
    out, _ = azure_to_kinect_v2(joints, levels)
    for v2, k4 in enumerate(AZURE_TO_KINECT_V2):
        x, y, z = joints[k4]
        np.testing.assert_allclose(out[v2], (-x / 1000, -y / 1000, z / 1000), rtol=1e-6)


@pytest.mark.parametrize(("level", "state"), [(0, 0), (1, 1), (2, 2), (3, 2)])
def test_azure_confidence_levels(level: int, state: int) -> None:
    joints, levels = _azure_body()
    levels[:] = level
    _, states = azure_to_kinect_v2(joints, levels)
    np.testing.assert_array_equal(states, np.full(25, state, dtype=np.uint8))


def test_azure_confidence_follows_the_joint_mapping() -> None:
    joints, levels = _azure_body()
    head = AZURE_TO_KINECT_V2[JointId.HEAD]
    levels[head] = 0
    levels[AZURE_TO_KINECT_V2[JointId.HAND_LEFT]] = 1
    levels[4] = 0  # CLAVICLE_LEFT: not in the v2 set, must not matter
    _, states = azure_to_kinect_v2(joints, levels)
    assert states[JointId.HEAD] == TrackingState.NOT_TRACKED
    assert states[JointId.HAND_LEFT] == TrackingState.INFERRED
    assert (np.delete(states, [JointId.HEAD, JointId.HAND_LEFT]) == TrackingState.TRACKED).all()


def test_azure_accepts_lists() -> None:
    joints, levels = _azure_body()
    out, states = azure_to_kinect_v2(joints.tolist(), levels.tolist())
    expected, expected_states = azure_to_kinect_v2(joints, levels)
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(states, expected_states)


@pytest.mark.parametrize(
    ("joint_shape", "level_shape"),
    [((25, 3), (32,)), ((32, 2), (32,)), ((32,), (32,)), ((32, 3), (25,)), ((32, 3), (32, 1))],
)
def test_azure_rejects_bad_shapes(
    joint_shape: tuple[int, ...], level_shape: tuple[int, ...]
) -> None:
    with pytest.raises(ValueError, match="expected"):
        azure_to_kinect_v2(np.zeros(joint_shape), np.full(level_shape, 2))


@pytest.mark.parametrize("bad", [-1, 4, 255])
def test_azure_rejects_bad_levels(bad: int) -> None:
    joints, levels = _azure_body()
    levels[7] = bad
    with pytest.raises(ValueError, match=r"0\.\.3"):
        azure_to_kinect_v2(joints, levels)


# --- bone lengths -----------------------------------------------------------------------------


def _known_skeleton() -> tuple[np.ndarray, np.ndarray]:
    """Joints built bone by bone with chosen offsets; returns (joints, expected lengths)."""
    rng = np.random.default_rng(7)
    offsets = rng.normal(size=(JOINT_COUNT, 3))
    lengths = rng.uniform(0.03, 0.5, size=JOINT_COUNT)
    offsets *= (lengths / np.linalg.norm(offsets, axis=1))[:, None]
    joints = np.zeros((JOINT_COUNT, 3))
    joints[JointId.SPINE_BASE] = (0.2, 1.0, 2.5)
    order: list[int] = [int(JointId.SPINE_BASE)]
    while len(order) < JOINT_COUNT:  # parents before children
        order += [j for j in range(JOINT_COUNT) if PARENTS[j] in order and j not in order]
    for joint in order[1:]:
        joints[joint] = joints[PARENTS[joint]] + offsets[joint]
    expected = np.array([lengths[child] for _, child in BONES])
    return joints, expected


def test_bone_lengths_known_skeleton() -> None:
    joints, expected = _known_skeleton()
    lengths = bone_lengths(joints)
    assert lengths.shape == (24,)
    assert lengths.dtype == np.float64
    np.testing.assert_allclose(lengths, expected, rtol=1e-12)


def test_bone_lengths_simple_chain() -> None:
    joints = np.zeros((JOINT_COUNT, 3), dtype=np.float32)
    joints[JointId.SPINE_MID] = (0.0, 0.3, 0.0)
    joints[JointId.SPINE_SHOULDER] = (0.0, 0.6, 0.0)
    joints[JointId.NECK] = (0.0, 0.7, 0.0)
    joints[JointId.HEAD] = (0.0, 0.7, 0.2)
    joints[JointId.SHOULDER_LEFT] = (-0.3, 0.6, -0.4)  # 3-4-5 triangle from SpineShoulder
    lengths = dict(zip(BONES, bone_lengths(joints), strict=True))
    assert lengths[(JointId.SPINE_BASE, JointId.SPINE_MID)] == pytest.approx(0.3)
    assert lengths[(JointId.SPINE_MID, JointId.SPINE_SHOULDER)] == pytest.approx(0.3)
    assert lengths[(JointId.SPINE_SHOULDER, JointId.NECK)] == pytest.approx(0.1)
    assert lengths[(JointId.NECK, JointId.HEAD)] == pytest.approx(0.2)
    assert lengths[(JointId.SPINE_SHOULDER, JointId.SHOULDER_LEFT)] == pytest.approx(0.5)


def test_bone_lengths_batch_nan_and_invariance() -> None:
    joints, expected = _known_skeleton()
    batch = np.stack([joints, joints + 10.0, joints[list(MIRROR_PERMUTATION)]])
    lengths = bone_lengths(batch)
    assert lengths.shape == (3, 24)
    np.testing.assert_allclose(lengths[0], expected)
    np.testing.assert_allclose(lengths[1], expected, rtol=1e-9)  # translation invariant
    # Mirroring relabels joints, so bone (p, c) takes the length of bone (mirror p, mirror c).
    index = {bone: i for i, bone in enumerate(BONES)}
    mirrored = [index[(MIRROR_PERMUTATION[p], MIRROR_PERMUTATION[c])] for p, c in BONES]
    np.testing.assert_allclose(lengths[2], expected[mirrored])
    with_nan = joints.copy()
    with_nan[JointId.WRIST_LEFT] = np.nan
    result = bone_lengths(with_nan)
    touching = [i for i, b in enumerate(BONES) if JointId.WRIST_LEFT in b]
    assert len(touching) == 3  # ElbowLeft-WristLeft, WristLeft-HandLeft, WristLeft-ThumbLeft
    assert np.isnan(result[touching]).all()
    assert np.isfinite(np.delete(result, touching)).all()


# --- transforms ---------------------------------------------------------------------------------

FORWARD = np.array([0.0, 0.0, 1.0])  # sensor +Z
LEFT = np.array([1.0, 0.0, 0.0])  # sensor +X
UP = np.array([0.0, 1.0, 0.0])  # sensor +Y


def _axis(transform: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """A sensor-frame direction expressed in the world."""
    direction: np.ndarray = transform[:3, :3] @ axis
    return direction


def test_yaw_zero_looks_along_plus_z() -> None:
    pose = pose_from_position_yaw_pitch((1.0, 2.0, 3.0), 0.0)
    np.testing.assert_allclose(_axis(pose, FORWARD), (0, 0, 1), atol=1e-12)
    np.testing.assert_allclose(_axis(pose, LEFT), (1, 0, 0), atol=1e-12)
    np.testing.assert_allclose(_axis(pose, UP), (0, 1, 0), atol=1e-12)
    np.testing.assert_allclose(pose[:3, 3], (1, 2, 3))
    np.testing.assert_allclose(pose[3], (0, 0, 0, 1))


def test_yaw_90_looks_along_plus_x() -> None:
    pose = pose_from_position_yaw_pitch((0.0, 1.0, 0.0), 90.0)
    np.testing.assert_allclose(_axis(pose, FORWARD), (1, 0, 0), atol=1e-12)
    np.testing.assert_allclose(_axis(pose, UP), (0, 1, 0), atol=1e-12)
    # right-handed turn about +Y: the sensor's left (+X) swings to world -Z
    np.testing.assert_allclose(_axis(pose, LEFT), (0, 0, -1), atol=1e-12)


def test_positive_pitch_looks_down() -> None:
    pose = pose_from_position_yaw_pitch((0.0, 2.0, 0.0), 0.0, 30.0)
    forward = _axis(pose, FORWARD)
    np.testing.assert_allclose(forward, (0, -0.5, math.sqrt(3) / 2), atol=1e-12)
    np.testing.assert_allclose(_axis(pose, LEFT), (1, 0, 0), atol=1e-12)  # no roll
    assert _axis(pose, UP)[1] > 0
    tilted = pose_from_position_yaw_pitch((0.0, 2.0, 0.0), 90.0, 20.0)
    forward = _axis(tilted, FORWARD)
    assert forward[1] == pytest.approx(-math.sin(math.radians(20)))
    assert forward[0] == pytest.approx(math.cos(math.radians(20)))


def test_huge_entries_are_not_rigid_without_overflowing() -> None:
    """An imported file may hold any numbers (issue 12's fuzzing): 1e200s would overflow R @ R.T
    (a RuntimeWarning, an error under pytest) before the answer, which is simply no."""
    huge = np.eye(4)
    huge[0, 1] = 1e200
    assert not is_rigid(huge)
    assert not is_rigid(np.diag([2.0, 1.0, 1.0, 1.0]))


@pytest.mark.parametrize(
    ("yaw", "pitch"), [(0, 0), (90, 0), (-135, 10), (33.3, -45), (180, 89), (720, 5)]
)
def test_pose_is_rigid(yaw: float, pitch: float) -> None:
    pose = pose_from_position_yaw_pitch((0.5, 1.5, -2.0), yaw, pitch)
    assert pose.shape == (4, 4)
    assert pose.dtype == np.float64
    assert is_rigid(pose)
    rotation = pose[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    assert abs(_axis(pose, LEFT)[1]) < 1e-12  # level roll: the left axis stays horizontal


@pytest.mark.parametrize(
    ("position", "target"),
    [
        ((0.0, 1.0, 0.0), (0.0, 1.0, 5.0)),
        ((0.0, 2.0, 0.0), (3.0, 1.0, 3.0)),
        ((-2.0, 2.5, 4.0), (0.0, 0.0, 0.0)),
        ((1.0, 0.5, 1.0), (1.0, 1.5, -2.0)),
        ((3.0, 1.0, -1.0), (-3.0, 1.0, -1.0)),
    ],
)
def test_look_at_aims_plus_z_at_the_target(
    position: tuple[float, float, float], target: tuple[float, float, float]
) -> None:
    pose = look_at_pose(position, target)
    assert is_rigid(pose)
    np.testing.assert_allclose(pose[:3, 3], position)
    direction = np.subtract(target, position)
    np.testing.assert_allclose(
        _axis(pose, FORWARD), direction / np.linalg.norm(direction), atol=1e-12
    )
    assert abs(_axis(pose, LEFT)[1]) < 1e-12
    assert _axis(pose, UP)[1] > 0
    # The target lies on the sensor's optical axis, at its distance.
    in_sensor = apply(invert(pose), np.array(target))
    expected = np.array([0.0, 0.0, float(np.linalg.norm(direction))])
    np.testing.assert_allclose(in_sensor, expected, atol=1e-12)


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    return pose_from_position_yaw_pitch(
        tuple(rng.uniform(-5, 5, size=3)), rng.uniform(-180, 180), rng.uniform(-80, 80)
    )


def test_invert_composes_to_identity() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        pose = _random_pose(rng)
        inverse = invert(pose)
        assert is_rigid(inverse)
        np.testing.assert_allclose(inverse @ pose, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(pose @ inverse, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(invert(inverse), pose, atol=1e-12)
        np.testing.assert_allclose(inverse, np.linalg.inv(pose), atol=1e-12)


def test_apply_matches_homogeneous_product_and_keeps_shape() -> None:
    rng = np.random.default_rng(4)
    pose = _random_pose(rng)
    points = rng.normal(size=(6, 25, 3))
    out = apply(pose, points)
    assert out.shape == (6, 25, 3)
    homogeneous = np.concatenate([points, np.ones((6, 25, 1))], axis=-1) @ pose.T
    np.testing.assert_allclose(out, homogeneous[..., :3], atol=1e-12)
    np.testing.assert_allclose(apply(invert(pose), out), points, atol=1e-12)
    single = apply(pose, [0.0, 0.0, 0.0])
    np.testing.assert_allclose(single, pose[:3, 3])


def test_apply_keeps_nan() -> None:
    pose = _random_pose(np.random.default_rng(5))
    points = np.array([[0.1, 0.2, 0.3], [np.nan, np.nan, np.nan], [1.0, np.nan, 2.0]])
    out = apply(pose, points)
    assert np.isfinite(out[0]).all()
    assert np.isnan(out[1]).all()
    assert np.isnan(out[2]).any()
    np.testing.assert_allclose(out[0], pose[:3, :3] @ points[0] + pose[:3, 3])


def test_is_rigid_rejects() -> None:
    pose = pose_from_position_yaw_pitch((0.0, 1.0, 0.0), 30.0, 10.0)
    assert is_rigid(pose)
    scaled = pose.copy()
    scaled[:3, :3] *= 1.01
    mirrored = pose @ np.diag([-1.0, 1.0, 1.0, 1.0])
    bottom = pose.copy()
    bottom[3, 0] = 0.5
    with_nan = pose.copy()
    with_nan[0, 3] = np.nan
    for bad in (scaled, mirrored, bottom, with_nan, np.eye(3), np.zeros((4, 4))):
        assert not is_rigid(bad)
