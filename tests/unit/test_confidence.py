"""Body-based confidence terms: bone length with chain propagation, range of motion; facing
cosines."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.agent.sim.performer import BodyShape, Pose, pose_joints
from skelfuse.fusion.anatomy import CHAIN_ORDER, facing_direction, joint_angles
from skelfuse.fusion.confidence import body_weights, range_of_motion_factors
from skelfuse.fusion.settings import FusionSettings, WeightSettings
from skelfuse.fusion.view_factors import facing_cosines
from skelfuse.protocol.skeleton import BONES, MIRROR_PERMUTATION, PARENTS, JointId, bone_lengths

J = JointId


def body(pose: Pose | None = None, heading: float = 0.0) -> np.ndarray:
    return pose_joints(BodyShape(1.75), pose or Pose(), (0.0, 0.0), heading)


def test_chain_order_puts_parents_first() -> None:
    seen: set[int] = set()
    for joint in CHAIN_ORDER:
        assert PARENTS[joint] < 0 or PARENTS[joint] in seen
        seen.add(joint)


def bone_terms(view: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(25,) the bone-length term alone (scale 5 cm), propagated (state weights 1, no other
    term)."""
    settings = FusionSettings(
        weights=WeightSettings(
            state_weights=(1.0, 1.0, 1.0), range_of_motion=False, bone_length_scale_m=0.05
        )
    )
    states = np.full((1, 25), 2, dtype=np.uint8)
    weights: np.ndarray = body_weights(view[None], states, reference[None], None, settings)[0]
    return weights


def test_bone_length_exact_is_one_and_falls_with_the_error() -> None:
    view = body()
    reference = bone_lengths(view)
    assert np.allclose(bone_terms(view, reference), 1.0)
    forearm = BONES.index((J.ELBOW_RIGHT, J.WRIST_RIGHT))
    longer = reference.copy()
    longer[forearm] -= 0.05
    factors = bone_terms(view, longer)
    assert factors[J.WRIST_RIGHT] == pytest.approx(np.exp(-1.0))
    assert factors[J.HAND_RIGHT] == pytest.approx(np.exp(-1.0))  # propagated outward
    assert factors[J.ELBOW_RIGHT] == pytest.approx(1.0)
    # Unknown reference: no evidence either way.
    assert np.allclose(bone_terms(view, np.full(24, np.nan)), 1.0)


def test_doubtful_elbow_makes_the_wrist_and_hand_doubtful() -> None:
    view = body()
    reference = bone_lengths(view)
    view[J.ELBOW_RIGHT] += [0.0, -0.10, 0.0]  # upper arm 10 cm longer, forearm 10 cm shorter
    chained = bone_terms(view, reference)
    assert chained[J.ELBOW_RIGHT] < 0.5
    for joint in (J.WRIST_RIGHT, J.HAND_RIGHT, J.HAND_TIP_RIGHT, J.THUMB_RIGHT):
        assert chained[joint] <= chained[J.ELBOW_RIGHT] + 1e-12
    assert chained[J.WRIST_LEFT] == pytest.approx(1.0)
    assert chained[J.SPINE_BASE] == pytest.approx(1.0)


def test_true_poses_are_within_range_of_motion() -> None:
    for pose in (Pose(), Pose(knee_flex_l=1.5, hip_flex_l=1.2), Pose(elbow_flex_r=2.0),
                 Pose(shoulder_abd_l=2.8, shoulder_abd_r=2.8)):  # fmt: skip
        assert np.allclose(range_of_motion_factors(body(pose)[None], 15.0), 1.0)


def test_knee_angle_is_signed_and_mirroring_makes_it_hyperextended() -> None:
    view = body(Pose(knee_flex_l=0.8, knee_flex_r=0.8), heading=1.0)
    angles = joint_angles(view[None])
    assert angles["knee_flexion_left"][0][0] == pytest.approx(np.degrees(0.8), abs=1e-6)
    mirrored = view[list(MIRROR_PERMUTATION)][None]
    assert joint_angles(mirrored)["knee_flexion_left"][0][0] < -40
    factors = range_of_motion_factors(mirrored, 15.0)[0]
    assert factors[J.ANKLE_LEFT] < 0.1 and factors[J.FOOT_LEFT] < 0.1


def test_hyperextended_knee_is_penalised_smoothly() -> None:
    view = body(Pose(knee_flex_l=-np.radians(20.0)))
    factor = range_of_motion_factors(view[None], 15.0)[0, J.ANKLE_LEFT]
    assert factor == pytest.approx(np.exp(-15.0 / 15.0), rel=1e-6)


def test_facing_cosines() -> None:
    view = body(heading=0.0)  # faces +Z
    facing = facing_direction(view)
    np.testing.assert_allclose(facing, [0.0, 0.0, 1.0], atol=1e-9)
    sensors = np.array([[0.0, 1.0, 2.5], [2.5, 1.0, 0.0], [0.0, 1.0, -2.5], [np.nan] * 3])
    cos = facing_cosines(facing, view[J.SPINE_BASE], sensors)
    np.testing.assert_allclose(cos[:3], [1.0, 0.0, -1.0], atol=1e-9)
    assert np.isnan(cos[3])


def test_batched_facing_and_range_of_motion_match_single_skeletons() -> None:
    from skelfuse.fusion.anatomy import facing_directions, rom_factors_and_forward

    rng = np.random.default_rng(2)
    skeletons = np.stack([body(Pose()) + rng.normal(scale=0.05, size=(25, 3)) for _ in range(5)])
    skeletons[4, 0] = np.nan
    together = facing_directions(skeletons)
    for k in range(5):
        np.testing.assert_array_equal(together[k], facing_direction(skeletons[k]))
    factors, forward = rom_factors_and_forward(skeletons, 15.0)
    np.testing.assert_array_equal(factors, range_of_motion_factors(skeletons, 15.0))
    for k in range(5):
        np.testing.assert_array_equal(
            factors[k], range_of_motion_factors(skeletons[k : k + 1], 15.0)[0]
        )
    assert forward.shape == (5, 3)
