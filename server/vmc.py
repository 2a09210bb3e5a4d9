"""The fused skeleton as a VMC protocol humanoid avatar (protocol.vmc.info): pure mapping.

VMC carries a Unity humanoid: ``/VMC/Ext/Root/Pos`` the avatar's root transform and one
``/VMC/Ext/Bone/Pos`` per ``HumanBodyBones`` name, each ``(string) name, (float) local position
x y z, (float) local rotation x y z w`` in Unity's axes: left-handed, Y up, Z forward, X right.
Ours are right-handed with Y up; mirroring X maps one onto the other: a point ``(x, y, z)``
becomes ``(-x, y, z)`` and a rotation quaternion ``(x, y, z, w)`` becomes ``(x, -y, -z, w)``.
The rig of the feed's rotations (``recording/joint_orientations.py``) rests in a T-pose facing
+Z with the person's left at +X: after the mirror, a T-pose facing Unity's forward with the left
at -X, which is the rest pose a VRM avatar's normalized bones have (identity local rotations).

A Unity bone sits at a joint and its rotation aims the segment to its child; the feed's rotation
of joint ``j`` is that of the bone ending at ``j``. So each humanoid bone takes the rotation of
one of our joints (:data:`HUMANOID`): LeftUpperArm, at ShoulderLeft, turns like ElbowLeft's bone
(ShoulderLeft → ElbowLeft). Its local rotation is relative to its humanoid parent's; its local
position is its joint's offset from the parent bone's joint, in the parent bone's frame.

Left out (no joint of ours drives them): UpperChest, the toes, eyes, jaw and every finger (our
HandTip and Thumb joints are single points, not phalanges); SpineBase → HipLeft/HipRight are
inside Hips.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.geometry.quaternion import quaternion_multiply, quaternion_rotate
from skelfuse.protocol.skeleton import PARENTS, JointId

F64 = npt.NDArray[np.float64]

HUMANOID: Final[tuple[tuple[str, int, str | None], ...]] = (
    ("Hips", JointId.SPINE_BASE, None),
    ("Spine", JointId.SPINE_MID, "Hips"),
    ("Chest", JointId.SPINE_SHOULDER, "Spine"),
    ("Neck", JointId.NECK, "Chest"),
    ("Head", JointId.HEAD, "Neck"),
    ("LeftShoulder", JointId.SHOULDER_LEFT, "Chest"),
    ("LeftUpperArm", JointId.ELBOW_LEFT, "LeftShoulder"),
    ("LeftLowerArm", JointId.WRIST_LEFT, "LeftUpperArm"),
    ("LeftHand", JointId.HAND_LEFT, "LeftLowerArm"),
    ("RightShoulder", JointId.SHOULDER_RIGHT, "Chest"),
    ("RightUpperArm", JointId.ELBOW_RIGHT, "RightShoulder"),
    ("RightLowerArm", JointId.WRIST_RIGHT, "RightUpperArm"),
    ("RightHand", JointId.HAND_RIGHT, "RightLowerArm"),
    ("LeftUpperLeg", JointId.KNEE_LEFT, "Hips"),
    ("LeftLowerLeg", JointId.ANKLE_LEFT, "LeftUpperLeg"),
    ("LeftFoot", JointId.FOOT_LEFT, "LeftLowerLeg"),
    ("RightUpperLeg", JointId.KNEE_RIGHT, "Hips"),
    ("RightLowerLeg", JointId.ANKLE_RIGHT, "RightUpperLeg"),
    ("RightFoot", JointId.FOOT_RIGHT, "RightLowerLeg"),
)
"""Per humanoid bone (parents first): its name, the joint whose bone rotation it takes (the
bone ending there), and its humanoid parent (None: Hips, relative to the root)."""

_INDEX: Final = {name: k for k, (name, _, _) in enumerate(HUMANOID)}
_SOURCE: Final = np.array([source for _, source, _ in HUMANOID])
_PARENT: Final = np.array([-1 if p is None else _INDEX[p] for _, _, p in HUMANOID])
_AT: Final = np.array([0 if p is None else PARENTS[s] for _, s, p in HUMANOID])
"""The joint each humanoid bone sits at: where its segment starts (Hips: SpineBase)."""
_MIRROR_POINT: Final = np.array([-1.0, 1.0, 1.0])
_MIRROR_QUATERNION: Final = np.array([1.0, -1.0, -1.0, 1.0])


def to_unity_points(points: F64) -> F64:
    """Points or vectors (..., 3), right-handed Y up → Unity's left-handed axes."""
    result: F64 = np.asarray(points, dtype=np.float64) * _MIRROR_POINT
    return result


def to_unity_rotations(quaternions: F64) -> F64:
    """Rotations (..., 4) ``(x, y, z, w)``, right-handed → Unity's left-handed axes."""
    result: F64 = np.asarray(quaternions, dtype=np.float64) * _MIRROR_QUATERNION
    return result


def humanoid_pose(joints: F64, rotations: F64) -> tuple[F64, F64, npt.NDArray[np.bool_]]:
    """One person's humanoid bones, in :data:`HUMANOID` order, in Unity's axes.

    Args:
        joints: (25, 3) metres, world frame (right-handed, Y up), NaN where unknown.
        rotations: (25, 4) each joint's bone rotation in the world frame (the feed's
            ``rotations``).

    Returns:
        local positions (B, 3) metres (Hips: its world position), local rotations (B, 4)
        ``(x, y, z, w)`` (Hips: its world rotation), and (B,) True where the bone is known
        (its joint and its parent bone's joint are finite).
    """
    joints = np.asarray(joints, dtype=np.float64)
    world = np.asarray(rotations, dtype=np.float64)[_SOURCE]  # (B, 4)
    has_parent = _PARENT >= 0
    parent_world = np.where(
        has_parent[:, None], world[np.maximum(_PARENT, 0)], np.array([0.0, 0.0, 0.0, 1.0])
    )
    inverse = parent_world * np.array([-1.0, -1.0, -1.0, 1.0])
    local = quaternion_multiply(inverse, world)
    at = joints[_AT]
    offset = np.where(has_parent[:, None], at - joints[_AT[np.maximum(_PARENT, 0)]], at)
    local_position = quaternion_rotate(inverse, offset)
    known = np.asarray(np.isfinite(local_position).all(axis=1))
    return to_unity_points(local_position), to_unity_rotations(local), known
