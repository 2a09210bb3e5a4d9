"""The skeleton model: Kinect v2's 25 joints, the fused output's joint set.

Joint indices follow the Kinect for Windows SDK 2.0 ``JointType`` enum; parents orient the
SDK's bone list away from the root, SpineBase (``shared/conventions.md`` §1.1).

Other joint sets map onto this one here, and only here: Azure Kinect / Orbbec Femto bodies
(32 joints, millimetres, +X right, +Y down, +Z forward) with :func:`azure_to_kinect_v2`, so mixed
sensor types fuse together; the CMU motion-capture skeletons the simulator replays with
:data:`CMU_ASF_TO_KINECT_V2` and :data:`CMU_BVH_TO_KINECT_V2`. NTU RGB+D files are Kinect v2
already.

Frames
------
Sensor (camera) frame, as the Kinect v2 SDK reports it: +X to the sensor's left, +Y up, +Z out
along the view direction, metres, right-handed. World frame: right-handed, +Y up, metres,
floor at y = 0. ``T_world_from_sensor`` (4×4) maps sensor points into the world:
``p_world = T_world_from_sensor @ p_sensor``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from enum import IntEnum
from types import MappingProxyType
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

BONE_NAMES: Final[tuple[str, ...]] = tuple(
    f"{JointId(p).name.lower()}-{JointId(c).name.lower()}" for p, c in BONES
)
"""Bone names for the API, in :data:`BONES` order: ``parent-child`` in snake case, e.g.
``hip_right-knee_right``."""

CHILDREN: Final[tuple[tuple[int, ...], ...]] = tuple(
    tuple(c for c in range(JOINT_COUNT) if PARENTS[c] == j) for j in range(JOINT_COUNT)
)
"""Child joints of each joint, in index order (none for the tips)."""

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


# --- CMU motion capture (the simulator's recorded motion) ------------------------------------
#
# ASF points are *bone ends* (``root`` is the root position); BVH points are *joint origins*
# (``X.end`` is the End Site of joint X; names match case-insensitively). Both CMU layouts
# describe the same body model: the BVH ``lhand`` joint sits on the wrist and ``LFingers`` one
# hand bone further, like the ASF ``lwrist`` end and ``lhand`` end. Left/right are the person's
# own (CMU: facing +Z, the left side is +X, which is also the Kinect world convention: left =
# up × facing); the right-side joints mirror the left ones.
#
# =============  =====================================  ===================================
# Kinect v2      ASF bone ends (CMU ``02.asf``)          BVH joints (CMU cgspeed naming)
# =============  =====================================  ===================================
# SpineBase      ``root`` (pelvis centre)                ``Hips``
# SpineMid       ½(``lowerback`` + ``upperback``):       ``Chest``: halfway along the
#                halfway along the spine chain           spine chain Hips → Chest2
#                root → thorax end (*derived*)
# SpineShoulder  ``thorax`` (base of the neck; the       ``Chest2`` (where the neck and the
#                clavicles start here)                   collars start)
# Neck           ``lowerneck`` (middle of the neck)      ``Neck``
# Head           ½(``upperneck`` + ``head``): middle     ½(``Head`` + ``Head.end``): middle
#                of the head bone ≈ head centre          of the head bone (*derived*)
#                (*derived*)
# ShoulderLeft   ``lclavicle`` (upper arm start)         ``LeftShoulder``
# ElbowLeft      ``lhumerus``                            ``LeftElbow``
# WristLeft      ``lwrist`` (after the forearm-twist     ``LeftWrist``
#                segment, where hand flexion happens)
# HandLeft       ``lhand`` (finger base, ~4 cm past      ``LFingers``
#                the wrist)
# HandTipLeft    ``lfingers`` (end of the finger bone)   ``LFingers.end``
# ThumbLeft      ``lthumb``                              ``LThumb.end``
# HipLeft        ``lhipjoint`` (upper leg start)         ``LeftHip``
# KneeLeft       ``lfemur``                              ``LeftKnee``
# AnkleLeft      ``ltibia``                              ``LeftAnkle``
# FootLeft       ``lfoot`` (toe base, ball of the foot)  ``LeftToe``
# (right side)   ``r…`` bones likewise                   ``Right…`` / ``R…`` likewise
# =============  =====================================  ===================================
#
# Caveats: the CMU hand is coarse (wrist → "fingers" end is only ~7 cm, so HandTip lies short
# of real fingertips); the SpineMid and Head points are derived, so their bones are only nearly
# rigid (length CV ~0.05 %).

JointRecipe = Mapping[JointId, tuple[tuple[str, float], ...]]
"""For each Kinect v2 joint, the weighted sum of another skeleton's named points it is."""


def _with_right_side(
    left: Mapping[JointId, tuple[tuple[str, float], ...]], rename: Callable[[str], str]
) -> dict[JointId, tuple[tuple[str, float], ...]]:
    """The left-side entries plus their mirror images, each point renamed by ``rename``."""
    out = dict(left)
    for joint, terms in left.items():
        out[JointId(MIRROR_PERMUTATION[joint])] = tuple((rename(name), w) for name, w in terms)
    return out


_J = JointId
_ASF_LEFT: Final = {
    _J.SHOULDER_LEFT: (("lclavicle", 1.0),),
    _J.ELBOW_LEFT: (("lhumerus", 1.0),),
    _J.WRIST_LEFT: (("lwrist", 1.0),),
    _J.HAND_LEFT: (("lhand", 1.0),),
    _J.HAND_TIP_LEFT: (("lfingers", 1.0),),
    _J.THUMB_LEFT: (("lthumb", 1.0),),
    _J.HIP_LEFT: (("lhipjoint", 1.0),),
    _J.KNEE_LEFT: (("lfemur", 1.0),),
    _J.ANKLE_LEFT: (("ltibia", 1.0),),
    _J.FOOT_LEFT: (("lfoot", 1.0),),
}
CMU_ASF_TO_KINECT_V2: Final[JointRecipe] = MappingProxyType(
    {
        _J.SPINE_BASE: (("root", 1.0),),
        _J.SPINE_MID: (("lowerback", 0.5), ("upperback", 0.5)),
        _J.SPINE_SHOULDER: (("thorax", 1.0),),
        _J.NECK: (("lowerneck", 1.0),),
        _J.HEAD: (("upperneck", 0.5), ("head", 0.5)),
        **_with_right_side(_ASF_LEFT, lambda name: "r" + name[1:]),
    }
)
"""Kinect v2 joint ← weighted sum of CMU ASF bone ends (``root`` = root position)."""

_BVH_LEFT: Final = {
    _J.SHOULDER_LEFT: (("LeftShoulder", 1.0),),
    _J.ELBOW_LEFT: (("LeftElbow", 1.0),),
    _J.WRIST_LEFT: (("LeftWrist", 1.0),),
    _J.HAND_LEFT: (("LFingers", 1.0),),
    _J.HAND_TIP_LEFT: (("LFingers.end", 1.0),),
    _J.THUMB_LEFT: (("LThumb.end", 1.0),),
    _J.HIP_LEFT: (("LeftHip", 1.0),),
    _J.KNEE_LEFT: (("LeftKnee", 1.0),),
    _J.ANKLE_LEFT: (("LeftAnkle", 1.0),),
    _J.FOOT_LEFT: (("LeftToe", 1.0),),
}
CMU_BVH_TO_KINECT_V2: Final[JointRecipe] = MappingProxyType(
    {
        _J.SPINE_BASE: (("Hips", 1.0),),
        _J.SPINE_MID: (("Chest", 1.0),),
        _J.SPINE_SHOULDER: (("Chest2", 1.0),),
        _J.NECK: (("Neck", 1.0),),
        _J.HEAD: (("Head", 0.5), ("Head.end", 0.5)),
        **_with_right_side(
            _BVH_LEFT,
            lambda name: "Right" + name[4:] if name.startswith("Left") else "R" + name[1:],
        ),
    }
)
"""Kinect v2 joint ← weighted sum of CMU BVH joint origins (``X.end`` = End Site of X)."""
