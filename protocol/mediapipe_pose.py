"""MediaPipe Pose's 33 landmarks → the 25-joint model, in metres in the camera's sensor frame.

Pure numpy (no cv2, no mediapipe): the ``mono`` agent source calls it per frame, and the offline
``skelfuse mocap``, calibration and benchmarks can call it on stored landmarks
(``tests/data/mono_landmarks.npz``, made by ``scripts/mono_landmarks.py``).

MediaPipe gives per landmark (``shared/conventions.md`` §1.4, the legacy ``solutions.pose`` API):

- image landmarks: pixels (x right, y down), here (33, 2) or (33, 3) with the third column unused;
- world landmarks: metres, origin between the hips, axes tied to the camera (+X right, +Y down,
  +Z away from the camera: OpenCV's camera axes), but **no translation**;
- visibility in [0, 1] (``presence`` is always 0 in that API and is not used).

Steps (:func:`body_from_landmarks` does all three):

1. :func:`place_landmarks`: the world landmarks placed in the camera frame by perspective-n-point
   against the image landmarks with the camera's intrinsics (:mod:`skelfuse.geometry.pnp`;
   ``mode="pose"`` fits rotation and translation, ``"translation"`` translation only). Each
   landmark's weight is its visibility. The depth this gives rests on MediaPipe's guess of the
   body's size, so its error lies mostly along the camera's viewing ray: the ``rgb`` sensor
   type's prior says so to fusion (fusion/priors.py).
2. :func:`landmark_states`: a visibility policy (:class:`StatePolicy`) → a TrackingState per
   landmark: Tracked at ``visibility >= tracked_min`` inside the image, else Inferred (MediaPipe
   always guesses a position), NotTracked only below ``inferred_min`` or where not finite.
3. :func:`to_kinect_v2`: the 25 joints (:data:`JOINTS_FROM_LANDMARKS`) with their states, axes
   turned to the wire's sensor frame (+X left, +Y up, +Z forward:
   :data:`~skelfuse.geometry.pinhole.CV_TO_SENSOR`). A joint made of several landmarks takes the
   worst of their states. Joints MediaPipe does not have are synthesised and never better than
   Inferred: SpineMid (halfway up the trunk), Neck (a third of the way from SpineShoulder to
   Head), and the hand tips (MediaPipe's "index" is a knuckle, not the fingertip Kinect means).

Left and right are the person's in both MediaPipe and Kinect, so no side swap happens here.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Final, Literal

import numpy as np
import numpy.typing as npt

from skelfuse.geometry.pinhole import CV_TO_SENSOR, Intrinsics
from skelfuse.geometry.pnp import Placement, solve_pose, solve_translation
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState

FloatArray = npt.NDArray[np.float64]
LANDMARK_COUNT: Final = 33


class Landmark(IntEnum):
    """MediaPipe Pose landmark indices (``PoseLandmark``; left/right are the person's)."""

    NOSE = 0
    LEFT_EYE_INNER = 1
    LEFT_EYE = 2
    LEFT_EYE_OUTER = 3
    RIGHT_EYE_INNER = 4
    RIGHT_EYE = 5
    RIGHT_EYE_OUTER = 6
    LEFT_EAR = 7
    RIGHT_EAR = 8
    MOUTH_LEFT = 9
    MOUTH_RIGHT = 10
    LEFT_SHOULDER = 11
    RIGHT_SHOULDER = 12
    LEFT_ELBOW = 13
    RIGHT_ELBOW = 14
    LEFT_WRIST = 15
    RIGHT_WRIST = 16
    LEFT_PINKY = 17
    RIGHT_PINKY = 18
    LEFT_INDEX = 19
    RIGHT_INDEX = 20
    LEFT_THUMB = 21
    RIGHT_THUMB = 22
    LEFT_HIP = 23
    RIGHT_HIP = 24
    LEFT_KNEE = 25
    RIGHT_KNEE = 26
    LEFT_ANKLE = 27
    RIGHT_ANKLE = 28
    LEFT_HEEL = 29
    RIGHT_HEEL = 30
    LEFT_FOOT_INDEX = 31
    RIGHT_FOOT_INDEX = 32


_L, _J = Landmark, JointId
JOINTS_FROM_LANDMARKS: Final[dict[JointId, tuple[Landmark, ...]]] = {
    _J.SPINE_BASE: (_L.LEFT_HIP, _L.RIGHT_HIP),
    _J.SPINE_SHOULDER: (_L.LEFT_SHOULDER, _L.RIGHT_SHOULDER),
    _J.HEAD: (_L.LEFT_EAR, _L.RIGHT_EAR),
    _J.SHOULDER_LEFT: (_L.LEFT_SHOULDER,),
    _J.ELBOW_LEFT: (_L.LEFT_ELBOW,),
    _J.WRIST_LEFT: (_L.LEFT_WRIST,),
    _J.HAND_LEFT: (_L.LEFT_PINKY, _L.LEFT_INDEX),
    _J.HAND_TIP_LEFT: (_L.LEFT_INDEX,),
    _J.THUMB_LEFT: (_L.LEFT_THUMB,),
    _J.SHOULDER_RIGHT: (_L.RIGHT_SHOULDER,),
    _J.ELBOW_RIGHT: (_L.RIGHT_ELBOW,),
    _J.WRIST_RIGHT: (_L.RIGHT_WRIST,),
    _J.HAND_RIGHT: (_L.RIGHT_PINKY, _L.RIGHT_INDEX),
    _J.HAND_TIP_RIGHT: (_L.RIGHT_INDEX,),
    _J.THUMB_RIGHT: (_L.RIGHT_THUMB,),
    _J.HIP_LEFT: (_L.LEFT_HIP,),
    _J.KNEE_LEFT: (_L.LEFT_KNEE,),
    _J.ANKLE_LEFT: (_L.LEFT_ANKLE,),
    _J.FOOT_LEFT: (_L.LEFT_FOOT_INDEX,),
    _J.HIP_RIGHT: (_L.RIGHT_HIP,),
    _J.KNEE_RIGHT: (_L.RIGHT_KNEE,),
    _J.ANKLE_RIGHT: (_L.RIGHT_ANKLE,),
    _J.FOOT_RIGHT: (_L.RIGHT_FOOT_INDEX,),
}
"""Each directly mapped joint: the mean of these landmarks (``shared/conventions.md`` §1.6).
SpineMid and Neck are synthesised (:data:`SYNTHESISED`)."""

AT_MOST_INFERRED: Final = frozenset({_J.SPINE_MID, _J.NECK, _J.HAND_TIP_LEFT, _J.HAND_TIP_RIGHT})
"""Joints that are not what Kinect means by them (synthesised, or a knuckle for a fingertip):
never better than Inferred."""

SPINE_MID_FRACTION: Final = 0.5
"""SpineMid = SpineBase + this × (SpineShoulder − SpineBase) (the simulator's Kinect body: 0.52)."""
NECK_FRACTION: Final = 1.0 / 3.0
"""Neck = SpineShoulder + this × (Head − SpineShoulder) (the simulator's Kinect body: 0.36)."""

PlacementMode = Literal["pose", "translation"]


@dataclass(frozen=True, slots=True)
class StatePolicy:
    """How visibility becomes a TrackingState (``shared/conventions.md`` §1.6: visibility
    predicts error poorly, so only two thresholds, and fusion's Inferred weight does the rest).

    tracked_min: visibility at or above which a landmark inside the image is Tracked. 0.5 is
        MediaPipe's own drawing threshold (``drawing_utils._VISIBILITY_THRESHOLD``).
    inferred_min: visibility below which a landmark is NotTracked; 0 keeps every detected
        landmark at least Inferred.
    edge_margin_px: a landmark more than this outside the image is at most Inferred (MediaPipe
        extrapolates limbs beyond the frame).
    """

    tracked_min: float = 0.5
    inferred_min: float = 0.0
    edge_margin_px: float = 0.0


@dataclass(frozen=True, slots=True)
class MonoBody:
    """One person from one camera frame.

    joints_m: (25, 3) float32 metres, the wire's sensor frame (+X left, +Y up, +Z forward);
        NaN where NotTracked. states: (25,) uint8 TrackingState.
    placement: how the world landmarks were placed (OpenCV camera frame), for the next
        frame's start and for diagnostics (``rms_px``).
    """

    joints_m: npt.NDArray[np.float32]
    states: npt.NDArray[np.uint8]
    placement: Placement


def landmark_states(
    visibility: npt.ArrayLike,
    image_px: npt.ArrayLike | None = None,
    size_wh: tuple[int, int] | None = None,
    policy: StatePolicy = StatePolicy(),
) -> npt.NDArray[np.uint8]:
    """Each landmark's TrackingState from its visibility (and, given the image, its place).

    Args:
        visibility: (33,) in [0, 1]; NaN → NotTracked.
        image_px: (33, 2+) pixels, or None to skip the in-image test.
        size_wh: (width, height) of the image in pixels; needed with ``image_px``.
        policy: the thresholds.

    Returns:
        (33,) uint8 TrackingState values.

    Raises:
        ValueError: on a wrong shape, or ``image_px`` without ``size_wh``.
    """
    vis = np.asarray(visibility, dtype=np.float64)
    if vis.shape != (LANDMARK_COUNT,):
        raise ValueError(f"expected (33,) visibility, got {vis.shape}")
    finite = np.isfinite(vis)
    states = np.full(LANDMARK_COUNT, TrackingState.INFERRED, dtype=np.uint8)
    states[finite & (vis >= policy.tracked_min)] = TrackingState.TRACKED
    if image_px is not None:
        if size_wh is None:
            raise ValueError("image_px needs size_wh")
        px = np.asarray(image_px, dtype=np.float64)
        if px.ndim != 2 or px.shape[0] != LANDMARK_COUNT or px.shape[1] < 2:
            raise ValueError(f"expected (33, 2+) image landmarks, got {px.shape}")
        m = policy.edge_margin_px
        inside = (
            (px[:, 0] >= -m)
            & (px[:, 0] <= size_wh[0] + m)
            & (px[:, 1] >= -m)
            & (px[:, 1] <= size_wh[1] + m)
        )
        states[~inside & (states == TrackingState.TRACKED)] = TrackingState.INFERRED
        finite &= np.isfinite(px[:, :2]).all(axis=1)
    states[~finite | (vis < policy.inferred_min)] = TrackingState.NOT_TRACKED
    return states


def to_kinect_v2(
    points_cv: npt.ArrayLike, landmark_state: npt.ArrayLike
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """33 landmarks (camera frame) → the 25 joints in the wire's sensor frame, with states.

    Args:
        points_cv: (33, 3) metres, OpenCV camera frame (+X right, +Y down, +Z forward), e.g.
            :func:`place_landmarks`' output; any frame with those axes works (the hip-centred
            world landmarks give a hip-centred skeleton).
        landmark_state: (33,) TrackingState per landmark (:func:`landmark_states`).

    Returns:
        joints_m: (25, 3) float32, +X left, +Y up, +Z forward; NaN where NotTracked.
        states: (25,) uint8.

    Raises:
        ValueError: on wrong shapes.
    """
    p = np.asarray(points_cv, dtype=np.float64)
    s = np.asarray(landmark_state, dtype=np.uint8)
    if p.shape != (LANDMARK_COUNT, 3) or s.shape != (LANDMARK_COUNT,):
        raise ValueError(f"expected (33, 3) points and (33,) states, got {p.shape}, {s.shape}")
    joints = np.full((JOINT_COUNT, 3), np.nan)
    states = np.zeros(JOINT_COUNT, dtype=np.uint8)
    for joint, marks in JOINTS_FROM_LANDMARKS.items():
        index = list(marks)
        joints[joint] = p[index].mean(axis=0)
        states[joint] = s[index].min()
    base, chest, head = joints[_J.SPINE_BASE], joints[_J.SPINE_SHOULDER], joints[_J.HEAD]
    joints[_J.SPINE_MID] = base + SPINE_MID_FRACTION * (chest - base)
    states[_J.SPINE_MID] = min(states[_J.SPINE_BASE], states[_J.SPINE_SHOULDER])
    joints[_J.NECK] = chest + NECK_FRACTION * (head - chest)
    states[_J.NECK] = min(states[_J.SPINE_SHOULDER], states[_J.HEAD])
    capped = list(AT_MOST_INFERRED)
    states[capped] = np.minimum(states[capped], TrackingState.INFERRED)
    states[~np.isfinite(joints).all(axis=1)] = TrackingState.NOT_TRACKED
    joints[states == TrackingState.NOT_TRACKED] = np.nan
    return (joints * CV_TO_SENSOR).astype(np.float32), states


def place_landmarks(
    image_px: npt.ArrayLike,
    world_m: npt.ArrayLike,
    visibility: npt.ArrayLike,
    intrinsics: Intrinsics,
    mode: PlacementMode = "pose",
    initial: Placement | None = None,
) -> tuple[FloatArray, Placement]:
    """The world landmarks placed in the camera frame (perspective-n-point on the image ones).

    Args:
        image_px: (33, 2+) pixels. world_m: (33, 3) MediaPipe world landmarks, metres.
        visibility: (33,) each landmark's weight in the fit.
        intrinsics: the camera's.
        mode: ``"pose"`` (rotation and translation) or ``"translation"`` (world axes as they are).
        initial: a start for ``"pose"`` (the previous frame's placement), or None.

    Returns:
        (33, 3) float64 metres in the OpenCV camera frame, and the :class:`Placement`.

    Raises:
        skelfuse.geometry.pnp.PnPError: too few usable landmarks, or none in front of the camera.
        ValueError: on wrong shapes or an unknown mode.
    """
    px = np.asarray(image_px, dtype=np.float64)[:, :2]
    world = np.asarray(world_m, dtype=np.float64)
    if mode == "pose":
        placement = solve_pose(world, px, intrinsics, visibility, initial=initial)
    elif mode == "translation":
        placement = solve_translation(world, px, intrinsics, visibility)
    else:
        raise ValueError(f"mode must be 'pose' or 'translation', got {mode!r}")
    return placement.apply(world), placement


def body_from_landmarks(
    image_px: npt.ArrayLike,
    world_m: npt.ArrayLike,
    visibility: npt.ArrayLike,
    size_wh: tuple[int, int],
    intrinsics: Intrinsics,
    policy: StatePolicy = StatePolicy(),
    mode: PlacementMode = "pose",
    initial: Placement | None = None,
) -> MonoBody:
    """One frame's landmarks → one body in the camera's sensor frame (the three steps above).

    Args: as :func:`place_landmarks` and :func:`landmark_states`.

    Raises:
        skelfuse.geometry.pnp.PnPError: too few usable landmarks, or none in front of the camera.
        ValueError: on wrong shapes.
    """
    points, placement = place_landmarks(image_px, world_m, visibility, intrinsics, mode, initial)
    states = landmark_states(visibility, image_px, size_wh, policy)
    joints, joint_states = to_kinect_v2(points, states)
    return MonoBody(joints, joint_states, placement)
