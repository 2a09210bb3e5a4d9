"""The skeleton model: Kinect v2's 25 joints, the fused output's joint set.

Joint indices follow the Kinect for Windows SDK 2.0 ``JointType`` enum; parents orient the
SDK's bone list away from the root, SpineBase (``shared/conventions.md`` §1.1).

Azure Kinect / Orbbec Femto bodies (32 joints, millimetres, +X right, +Y down, +Z forward)
map onto this set with :func:`azure_to_kinect_v2`, so mixed sensor types fuse together.

Frames
------
Sensor (camera) frame, as the Kinect v2 SDK reports it: +X to the sensor's left, +Y up, +Z out
along the view direction, metres, right-handed. World frame: right-handed, +Y up, metres,
floor at y = 0. ``T_world_from_sensor`` (4×4) maps sensor points into the world:
``p_world = T_world_from_sensor @ p_sensor``.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

import numpy as np
import numpy.typing as npt

SKELETON_NAME: Final = "kinect_v2_25"


class JointId(IntEnum):
    """Kinect v2 ``JointType``: the value is the index on the wire and in every array."""

    SPINE_BASE = 0
    SPINE_MID = 1
    NECK = 2
    HEAD = 3
    SHOULDER_LEFT = 4
    ELBOW_LEFT = 5
    WRIST_LEFT = 6
    HAND_LEFT = 7
    SHOULDER_RIGHT = 8
    ELBOW_RIGHT = 9
    WRIST_RIGHT = 10
    HAND_RIGHT = 11
    HIP_LEFT = 12
    KNEE_LEFT = 13
    ANKLE_LEFT = 14
    FOOT_LEFT = 15
    HIP_RIGHT = 16
    KNEE_RIGHT = 17
    ANKLE_RIGHT = 18
    FOOT_RIGHT = 19
    SPINE_SHOULDER = 20
    HAND_TIP_LEFT = 21
    THUMB_LEFT = 22
    HAND_TIP_RIGHT = 23
    THUMB_RIGHT = 24


class TrackingState(IntEnum):
    """Kinect v2 per-joint ``TrackingState``."""

    NOT_TRACKED = 0
    INFERRED = 1
    TRACKED = 2


JOINT_COUNT: Final = 25
JOINT_NAMES: Final[tuple[str, ...]] = tuple(
    "".join(part.capitalize() for part in j.name.split("_")) for j in JointId
)
"""Names as the Kinect SDK spells them: ``SpineBase``, ``HandTipLeft``..."""

PARENTS: Final[tuple[int, ...]] = (
    -1, 0, 20, 2, 20, 4, 5, 6, 20, 8, 9, 10, 0, 12, 13, 14, 0, 16, 17, 18, 1, 7, 6, 11, 10,
)  # fmt: skip
"""Parent index of each joint; -1 for the root (SpineBase)."""

BONES: Final[tuple[tuple[int, int], ...]] = tuple(
    (parent, child) for child, parent in enumerate(PARENTS) if parent >= 0
)
"""(parent, child) pairs, 24 bones."""

_LEFT_RIGHT_PAIRS: Final = (
    (JointId.SHOULDER_LEFT, JointId.SHOULDER_RIGHT),
    (JointId.ELBOW_LEFT, JointId.ELBOW_RIGHT),
    (JointId.WRIST_LEFT, JointId.WRIST_RIGHT),
    (JointId.HAND_LEFT, JointId.HAND_RIGHT),
    (JointId.HIP_LEFT, JointId.HIP_RIGHT),
    (JointId.KNEE_LEFT, JointId.KNEE_RIGHT),
    (JointId.ANKLE_LEFT, JointId.ANKLE_RIGHT),
    (JointId.FOOT_LEFT, JointId.FOOT_RIGHT),
    (JointId.HAND_TIP_LEFT, JointId.HAND_TIP_RIGHT),
    (JointId.THUMB_LEFT, JointId.THUMB_RIGHT),
)


def _mirror_permutation() -> tuple[int, ...]:
    perm = list(range(JOINT_COUNT))
    for left, right in _LEFT_RIGHT_PAIRS:
        perm[left], perm[right] = int(right), int(left)
    return tuple(perm)


MIRROR_PERMUTATION: Final[tuple[int, ...]] = _mirror_permutation()
"""``joints[list(MIRROR_PERMUTATION)]`` swaps every left joint with its right counterpart."""


def _bone_mirror_permutation() -> tuple[int, ...]:
    index = {bone: b for b, bone in enumerate(BONES)}
    return tuple(index[(MIRROR_PERMUTATION[p], MIRROR_PERMUTATION[c])] for p, c in BONES)


BONE_MIRROR_PERMUTATION: Final[tuple[int, ...]] = _bone_mirror_permutation()
"""``lengths[list(BONE_MIRROR_PERMUTATION)]`` swaps every left bone with its right counterpart
(midline bones map to themselves)."""


def skeleton_definition() -> dict[str, object]:
    """The skeleton definition message apps receive on connect and at ``GET /api/skeleton``."""
    return {
        "type": "skeleton",
        "v": 1,
        "name": SKELETON_NAME,
        "joints": list(JOINT_NAMES),
        "parents": list(PARENTS),
        "bones": [list(b) for b in BONES],
        "units": "m",
        "up": "+y",
        "handedness": "right",
        "frame": "world: right-handed, +Y up, metres, floor at y = 0",
        "tracking_states": {s.name: int(s) for s in TrackingState},
    }


# --- Azure Kinect / Orbbec Femto (k4abt, 32 joints) -------------------------------------------

AZURE_JOINT_COUNT: Final = 32

AZURE_TO_KINECT_V2: Final[tuple[int, ...]] = (
    0,   # SpineBase      <- PELVIS
    1,   # SpineMid       <- SPINE_NAVEL
    3,   # Neck           <- NECK
    26,  # Head           <- HEAD
    5,   # ShoulderLeft   <- SHOULDER_LEFT
    6,   # ElbowLeft      <- ELBOW_LEFT
    7,   # WristLeft      <- WRIST_LEFT
    8,   # HandLeft       <- HAND_LEFT
    12,  # ShoulderRight  <- SHOULDER_RIGHT
    13,  # ElbowRight     <- ELBOW_RIGHT
    14,  # WristRight     <- WRIST_RIGHT
    15,  # HandRight      <- HAND_RIGHT
    18,  # HipLeft        <- HIP_LEFT
    19,  # KneeLeft       <- KNEE_LEFT
    20,  # AnkleLeft      <- ANKLE_LEFT
    21,  # FootLeft       <- FOOT_LEFT
    22,  # HipRight       <- HIP_RIGHT
    23,  # KneeRight      <- KNEE_RIGHT
    24,  # AnkleRight     <- ANKLE_RIGHT
    25,  # FootRight      <- FOOT_RIGHT
    2,   # SpineShoulder  <- SPINE_CHEST (approximate: the chest sits a little lower)
    9,   # HandTipLeft    <- HANDTIP_LEFT
    10,  # ThumbLeft      <- THUMB_LEFT
    16,  # HandTipRight   <- HANDTIP_RIGHT
    17,  # ThumbRight     <- THUMB_RIGHT
)  # fmt: skip
"""For each Kinect v2 joint, the k4abt joint index it is taken from (conventions.md §1.6)."""

AZURE_CONFIDENCE_TO_STATE: Final[tuple[int, ...]] = (
    TrackingState.NOT_TRACKED,  # K4ABT_JOINT_CONFIDENCE_NONE: out of range
    TrackingState.INFERRED,  # LOW: occluded, predicted
    TrackingState.TRACKED,  # MEDIUM: the most the current SDK emits
    TrackingState.TRACKED,  # HIGH: reserved for future SDKs
)

# Azure depth camera (+X right, +Y down, mm) -> Kinect-v2-like (+X left, +Y up, m).
_AZURE_AXES_TO_V2: Final = np.array([-1.0, -1.0, 1.0], dtype=np.float64) / 1000.0


def azure_to_kinect_v2(
    joints_mm: npt.ArrayLike, confidence_levels: npt.ArrayLike
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """Map one k4abt body onto the Kinect v2 joint set.

    Args:
        joints_mm: (32, 3) positions in the Azure/Femto depth camera frame, millimetres,
            +X right, +Y down, +Z forward.
        confidence_levels: (32,) ``k4abt_joint_confidence_level_t`` values 0..3.

    Returns:
        joints_m: (25, 3) float32, metres, Kinect v2 camera frame (+X left, +Y up, +Z forward).
        states: (25,) uint8 ``TrackingState`` values.

    Raises:
        ValueError: on a wrong shape or a confidence level outside 0..3.
    """
    joints = np.asarray(joints_mm, dtype=np.float64)
    levels = np.asarray(confidence_levels)
    if joints.shape != (AZURE_JOINT_COUNT, 3):
        raise ValueError(f"expected (32, 3) Azure joints in mm, got shape {joints.shape}")
    if levels.shape != (AZURE_JOINT_COUNT,):
        raise ValueError(f"expected (32,) confidence levels, got shape {levels.shape}")
    if levels.size and (levels.min() < 0 or levels.max() > 3):
        raise ValueError(f"confidence levels must be 0..3, got {sorted(set(levels.tolist()))}")
    index = np.asarray(AZURE_TO_KINECT_V2)
    joints_m = (joints[index] * _AZURE_AXES_TO_V2).astype(np.float32)
    states = np.asarray(AZURE_CONFIDENCE_TO_STATE, dtype=np.uint8)[levels[index].astype(int)]
    return joints_m, states


def bone_lengths(joints_m: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """Length of each bone in :data:`BONES` order.

    Args:
        joints_m: (..., 25, 3) joint positions in metres, any frame.

    Returns:
        (..., 24) float64 lengths in metres; NaN where either end is NaN.
    """
    joints = np.asarray(joints_m, dtype=np.float64)
    parents = np.array([b[0] for b in BONES])
    children = np.array([b[1] for b in BONES])
    diff = joints[..., children, :] - joints[..., parents, :]
    lengths: npt.NDArray[np.float64] = np.linalg.norm(diff, axis=-1)
    return lengths
