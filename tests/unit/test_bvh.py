"""protocol.bvh: the one BVH reader and writer (their use: test_mocap.py and test_export.py)."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.protocol.bvh import Bvh, BvhError, BvhJoint, format_bvh, forward_kinematics, parse_bvh
from skelfuse.protocol.transform import kabsch_rotation

ARM = (
    BvhJoint("Hips", -1, np.zeros(3), ("Xposition", "Yposition", "Zposition", "Zrotation")),
    BvhJoint("Arm", 0, np.array([1.0, 0.0, 0.0]), ("Zrotation", "Xrotation")),
    BvhJoint("Arm.end", 1, np.array([0.0, 2.0, 0.0]), end_site=True),
    BvhJoint("Leg", 0, np.array([0.0, -1.0, 0.0]), ("Xrotation",)),
    BvhJoint("Leg.end", 3, np.array([0.0, -2.0, 0.0]), end_site=True),
)
MOTION = np.array([[0, 0, 0, 0, 0, 0, 0], [1, 2, 3, 90, 0, 90, -90]], dtype=np.float64)


def test_written_file_reads_back_as_the_same_hierarchy_and_motion() -> None:
    text = format_bvh(Bvh(ARM, 1 / 30, 30.0, MOTION))
    assert "  End Site\n    {\n      OFFSET 0.000000 2.000000 0.000000\n    }" in text
    bvh = parse_bvh(text)
    assert [(j.name, j.parent, j.channels, j.end_site) for j in bvh.joints] == [
        (j.name, j.parent, j.channels, j.end_site) for j in ARM
    ]
    np.testing.assert_array_equal(np.stack([j.offset for j in bvh.joints]),
                                  np.stack([j.offset for j in ARM]))  # fmt: skip
    np.testing.assert_array_equal(bvh.motion, MOTION)
    assert bvh.fps == 30.0 and bvh.frame_time_s == pytest.approx(1 / 30)
    positions = forward_kinematics(bvh)
    # frame 1: root at (1, 2, 3) turned 90° about Z; the arm's own Rz(90)·Rx(90) sends +Y to +Z
    np.testing.assert_allclose(positions[1, bvh.index("Arm.end")], [1, 3, 5], atol=1e-12)
    # the leg hangs from (2, 2, 3) (the root's Rz(90) turns -Y to +X); its Rx(-90) turns -Y to +Z
    np.testing.assert_allclose(positions[1, bvh.index("Leg.end")], [2, 2, 5], atol=1e-12)


def test_position_channels_replace_the_offset_as_the_bvh_convention_says() -> None:
    # Blender's importer and bvhio place a joint with position channels at the channels' values
    # from its parent: OFFSET is only its rest pose (it used to be added here, which no other
    # reader does).
    joints = (
        BvhJoint("Hips", -1, np.array([5.0, 0.0, 0.0]), ("Xposition", "Yposition", "Zposition")),
        BvhJoint(
            "Arm",
            0,
            np.array([1.0, 0.0, 0.0]),
            ("Xposition", "Yposition", "Zposition", "Zrotation"),
        ),
        BvhJoint("Arm.end", 1, np.array([0.0, 2.0, 0.0]), end_site=True),
        BvhJoint("Leg", 0, np.array([0.0, -1.0, 0.0]), ("Yposition",)),
    )
    motion = np.array([[10.0, 20.0, 30.0, 0.0, 3.0, 0.0, 90.0, -4.0]])
    positions = forward_kinematics(parse_bvh(format_bvh(Bvh(joints, 1 / 30, 30.0, motion))))
    np.testing.assert_allclose(positions[0, 0], [10, 20, 30], atol=1e-12)
    np.testing.assert_allclose(positions[0, 1], [10, 23, 30], atol=1e-12)
    np.testing.assert_allclose(positions[0, 2], [8, 23, 30], atol=1e-12)  # Rz(90) turns +Y to -X
    np.testing.assert_allclose(positions[0, 3], [10, 16, 30], atol=1e-12)  # X, Z kept from OFFSET


def test_channel_names_are_spelled_as_bvh_does() -> None:
    text = format_bvh(Bvh(ARM, 1 / 30, 30.0, MOTION)).replace(
        "Zrotation Xrotation", "ZROTATION xrotation"
    )
    assert parse_bvh(text).joints[1].channels == ("Zrotation", "Xrotation")


def test_writer_refuses_what_it_could_not_write_faithfully() -> None:
    hand = BvhJoint("Hand", 2, np.ones(3), ("Xrotation",))  # under the arm's End Site
    with pytest.raises(ValueError, match="depth-first"):
        format_bvh(Bvh((*ARM[:3], hand), 1 / 30, 30.0, MOTION))
    with pytest.raises(ValueError, match=r"motion must be \(T, 7\)"):
        format_bvh(Bvh(ARM, 1 / 30, 30.0, MOTION[:, :6]))


def test_errors_name_the_source_and_line() -> None:
    text = format_bvh(Bvh(ARM, 1 / 30, 30.0, MOTION)).replace("OFFSET 1.000000", "OFFSET x")
    with pytest.raises(BvhError, match=r"take\.bvh:8: expected a number, got 'x'"):
        parse_bvh(text, "take.bvh")


def test_kabsch_rotation_recovers_a_rotation_and_never_reflects() -> None:
    rng = np.random.default_rng(4)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rotation = q * np.sign(np.linalg.det(q))
    src = rng.normal(size=(5, 3))
    np.testing.assert_allclose(kabsch_rotation(src, src @ rotation.T), rotation, atol=1e-12)
    mirrored = src * [-1.0, 1.0, 1.0]
    assert np.linalg.det(kabsch_rotation(src, mirrored)) == pytest.approx(1.0)
