"""MediaPipe's 33 landmarks → the 25-joint model, for the benchmark's landmark replay.

The benchmark's stand-in until the ``mono`` source's own mapping (issue 14 item 1) lands; the
same rules: joints MediaPipe has are Tracked when their visibility is ≥ 0.5, else Inferred;
joints made from others (SpineBase, SpineMid, SpineShoulder, Neck, Head, Hand) are never
better than Inferred, except SpineBase and SpineShoulder (midpoints of two landmarks) which
take the lower state of their two.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState

FloatArray = npt.NDArray[np.float64]

DIRECT: Final = {
    JointId.SHOULDER_LEFT: 11, JointId.SHOULDER_RIGHT: 12, JointId.ELBOW_LEFT: 13,
    JointId.ELBOW_RIGHT: 14, JointId.WRIST_LEFT: 15, JointId.WRIST_RIGHT: 16,
    JointId.HIP_LEFT: 23, JointId.HIP_RIGHT: 24, JointId.KNEE_LEFT: 25, JointId.KNEE_RIGHT: 26,
    JointId.ANKLE_LEFT: 27, JointId.ANKLE_RIGHT: 28, JointId.FOOT_LEFT: 31,
    JointId.FOOT_RIGHT: 32, JointId.HAND_TIP_LEFT: 19, JointId.HAND_TIP_RIGHT: 20,
    JointId.THUMB_LEFT: 21, JointId.THUMB_RIGHT: 22,
}  # fmt: skip
"""Joints that are one MediaPipe landmark (the hand tips are the index fingers)."""
TRACKED_VISIBILITY: Final = 0.5


def to_kinect25(
    points: FloatArray, visibility: FloatArray
) -> tuple[FloatArray, npt.NDArray[np.uint8]]:
    """33 landmarks (33, 3) in any frame, visibility (33,) → (25, 3) joints, same frame, and
    (25,) tracking states."""
    joints = np.full((JOINT_COUNT, 3), np.nan)
    states = np.zeros(JOINT_COUNT, dtype=np.uint8)
    good = visibility >= TRACKED_VISIBILITY
    tracked, inferred = int(TrackingState.TRACKED), int(TrackingState.INFERRED)
    for joint, lm in DIRECT.items():
        joints[joint] = points[lm]
        states[joint] = tracked if good[lm] else inferred

    def mid(a: int, b: int) -> FloatArray:
        return np.asarray((points[a] + points[b]) / 2, dtype=np.float64)

    joints[JointId.SPINE_BASE] = mid(23, 24)
    joints[JointId.SPINE_SHOULDER] = mid(11, 12)
    states[JointId.SPINE_BASE] = tracked if good[23] and good[24] else inferred
    states[JointId.SPINE_SHOULDER] = tracked if good[11] and good[12] else inferred
    joints[JointId.SPINE_MID] = (joints[JointId.SPINE_BASE] + joints[JointId.SPINE_SHOULDER]) / 2
    head = mid(7, 8)  # between the ears
    joints[JointId.HEAD] = head
    joints[JointId.NECK] = (joints[JointId.SPINE_SHOULDER] + head) / 2
    joints[JointId.HAND_LEFT] = mid(17, 19)  # pinky and index knuckles
    joints[JointId.HAND_RIGHT] = mid(18, 20)
    for joint in (JointId.SPINE_MID, JointId.NECK, JointId.HEAD, JointId.HAND_LEFT,
                  JointId.HAND_RIGHT):  # fmt: skip
        states[joint] = inferred
    bad = ~np.isfinite(joints).all(axis=1)
    states[bad] = int(TrackingState.NOT_TRACKED)
    return joints, states
