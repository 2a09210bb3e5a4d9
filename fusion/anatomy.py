"""The body's own geometry: kinematic chain order, body frame, joint angles, facing, yaw.

Pure functions on arrays of joints, (S, 25, 3) or (25, 3), metres, world frame (+Y up); NaN
where a joint is unknown. :mod:`skelfuse.fusion.confidence` turns the angles into confidence
terms; its docstring gives the sources of :data:`ROM_LIMITS_DEG`.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion import kernels, kernels_stages
from skelfuse.protocol.skeleton import JOINT_COUNT, PARENTS, JointId

FloatArray = npt.NDArray[np.float64]
J = JointId


def _topological_order() -> tuple[int, ...]:
    depth = [0] * JOINT_COUNT
    for joint in range(JOINT_COUNT):
        node, d = joint, 0
        while PARENTS[node] >= 0:
            node, d = PARENTS[node], d + 1
        depth[joint] = d
    return tuple(sorted(range(JOINT_COUNT), key=lambda j: (depth[j], j)))


CHAIN_ORDER: Final[tuple[int, ...]] = _topological_order()
"""Joints sorted so that every parent comes before its children (SpineBase first)."""


def _depth_levels() -> tuple[tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]], ...]:
    depth = {0: 0}
    for joint in CHAIN_ORDER[1:]:
        depth[joint] = depth[PARENTS[joint]] + 1
    levels = []
    for d in range(1, max(depth.values()) + 1):
        children = [j for j in CHAIN_ORDER if depth[j] == d]
        levels.append(
            (np.array(children, dtype=np.intp), np.array([PARENTS[j] for j in children], np.intp))
        )
    return tuple(levels)


CHAIN_LEVELS: Final = _depth_levels()
"""(children, their parents) per depth below SpineBase: each level only needs the one above."""


HORIZONTAL: Final = np.array([1.0, 0.0, 1.0])


def unit(v: FloatArray) -> FloatArray:
    """Unit vectors along the last axis (…, 3); NaN where a vector is zero or unknown."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return _unit(v)


def _unit(v: FloatArray) -> FloatArray:
    """:func:`unit` for callers already inside ``np.errstate(invalid=, divide="ignore")``."""
    norm = np.sqrt((v * v).sum(-1, keepdims=True))  # == np.linalg.norm(v, axis=-1)
    result: FloatArray = v / norm
    return result


# The body frame and the angles work on component-major arrays, (3, S, …): x, y and z are
# each one contiguous block, so a dot product or a cross product is a few whole-array
# operations (the same ones, in the same order, as on (…, 3) arrays: the same bits).


def _dot(a: FloatArray, b: FloatArray) -> FloatArray:
    """(…) dot products of component-major (3, …) arrays: (a₀b₀ + a₁b₁) + a₂b₂, the order a sum
    over a last axis of three takes."""
    result: FloatArray = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return result


def _unit_major(v: FloatArray) -> FloatArray:
    """:func:`unit` of a component-major (3, …) array (inside ``np.errstate``)."""
    result: FloatArray = v / np.sqrt(_dot(v, v))
    return result


_NEXT: Final = np.array([1, 2, 0])
_AFTER: Final = np.array([2, 0, 1])


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """``np.cross`` of component-major (3, …) arrays (the same operations, so the same bits):
    component k is a[k+1]·b[k+2] − a[k+2]·b[k+1], all three at once."""
    out: FloatArray = a[_NEXT] * b[_AFTER] - a[_AFTER] * b[_NEXT]
    return out


_ACROSS_LEFT: Final = np.array([J.HIP_LEFT, J.SHOULDER_LEFT])
_ACROSS_RIGHT: Final = np.array([J.HIP_RIGHT, J.SHOULDER_RIGHT])


def body_frame(views: npt.ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each view's own body axes, from its labels.

    Args:
        views: (S, 25, 3) joints, metres, world frame.

    Returns:
        left, up, forward: (S, 3) unit vectors (NaN where the trunk is missing). ``left`` is the
        mean of the hip and shoulder left-minus-right vectors made orthogonal to ``up``
        (SpineBase → SpineShoulder); ``forward = left × up``.
    """
    joints = np.asarray(views, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        left, up, forward = _body_frame(np.ascontiguousarray(joints.transpose(2, 0, 1)))
    return left.T.copy(), up.T.copy(), forward.T.copy()


def _body_frame(joints: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`body_frame` of component-major (3, S, 25) joints, inside ``np.errstate``: left,
    up, forward as (3, S)."""
    up = _unit_major(joints[:, :, J.SPINE_SHOULDER] - joints[:, :, J.SPINE_BASE])
    across = joints[:, :, _ACROSS_LEFT] - joints[:, :, _ACROSS_RIGHT]  # (3, S, 2): hips, shoulders
    ok: npt.NDArray[np.bool_] = np.isfinite(across)
    kept = np.where(ok, across, 0.0)
    lateral = kept[:, :, 0] + kept[:, :, 1]
    whole = ok[0] & ok[1] & ok[2]  # (S, 2): the hips, the shoulders known
    lateral[:, ~(whole[:, 0] | whole[:, 1])] = np.nan
    lateral = lateral - _dot(lateral, up) * up
    left = _unit_major(lateral)
    forward = _cross(left, up)
    return left, up, forward


ROM_LIMITS_DEG: Final[dict[str, tuple[float, float]]] = {
    "knee_flexion": (-5.0, 145.0),
    "elbow_flexion": (0.0, 150.0),
    "hip_flexion": (-30.0, 130.0),
    "hip_abduction": (-30.0, 50.0),
    "shoulder_extension": (-180.0, 60.0),
    "ankle_shank_foot": (25.0, 150.0),
    "neck_flexion": (0.0, 70.0),
}
"""Anatomical range of each angle (degrees); sources and conventions in the module docstring."""


# Both sides at once: index 0 left, 1 right (sign +1 / −1 for abduction).
_SIDE_SIGN: Final = np.array([1.0, -1.0])


_KNEE: Final = np.array([J.KNEE_LEFT, J.KNEE_RIGHT])


_ANKLE: Final = np.array([J.ANKLE_LEFT, J.ANKLE_RIGHT])


_FOOT: Final = np.array([J.FOOT_LEFT, J.FOOT_RIGHT])


_ELBOW: Final = np.array([J.ELBOW_LEFT, J.ELBOW_RIGHT])


_WRIST: Final = np.array([J.WRIST_LEFT, J.WRIST_RIGHT])


_SIDED_ANGLES: Final = (
    ("knee_flexion", _ANKLE),
    ("hip_flexion", _KNEE),
    ("hip_abduction", _KNEE),
    ("ankle_shank_foot", _FOOT),
    ("elbow_flexion", _WRIST),
    ("shoulder_extension", _ELBOW),
)
"""The per-side angles in the order :func:`_angle_table` returns them, and their distal joints."""


_ANGLE_LOW: Final = np.array(
    [ROM_LIMITS_DEG[name][0] for name, _ in _SIDED_ANGLES for _side in range(2)]
    + [ROM_LIMITS_DEG["neck_flexion"][0]]
)


_ANGLE_HIGH: Final = np.array(
    [ROM_LIMITS_DEG[name][1] for name, _ in _SIDED_ANGLES for _side in range(2)]
    + [ROM_LIMITS_DEG["neck_flexion"][1]]
)
ANGLE_LIMITS: Final = (_ANGLE_LOW, _ANGLE_HIGH)
"""The angle table's limits, low and high (13,), degrees: what the compiled kernels take."""

_KNEE_COLUMNS: Final = (2, 3, 4, 5)
"""Columns of the angle table landing on the knees (hip flexion L/R, hip abduction L/R)."""


_SINGLE_COLUMNS: Final = np.array([0, 1, 6, 7, 8, 9, 10, 11, 12])


_SINGLE_JOINTS: Final = np.array(
    [J.ANKLE_LEFT, J.ANKLE_RIGHT, J.FOOT_LEFT, J.FOOT_RIGHT, J.WRIST_LEFT, J.WRIST_RIGHT,
     J.ELBOW_LEFT, J.ELBOW_RIGHT, J.HEAD]
)  # fmt: skip


# The segments the angles need, as distal − proximal joint: thigh, shank, foot, upper arm,
# forearm (left, right each), then the neck.
_SEGMENT_DISTAL: Final = np.array(
    [J.KNEE_LEFT, J.KNEE_RIGHT, J.ANKLE_LEFT, J.ANKLE_RIGHT, J.FOOT_LEFT, J.FOOT_RIGHT,
     J.ELBOW_LEFT, J.ELBOW_RIGHT, J.WRIST_LEFT, J.WRIST_RIGHT, J.HEAD]
)  # fmt: skip
_SEGMENT_PROXIMAL: Final = np.array(
    [J.HIP_LEFT, J.HIP_RIGHT, J.KNEE_LEFT, J.KNEE_RIGHT, J.ANKLE_LEFT, J.ANKLE_RIGHT,
     J.SHOULDER_LEFT, J.SHOULDER_RIGHT, J.ELBOW_LEFT, J.ELBOW_RIGHT, J.NECK]
)  # fmt: skip
_LIMBS: Final = np.array([0, 1, 6, 7])
"""Thighs and upper arms among the segments: each swings forward or back from the trunk."""
_TO_UNIT: Final = np.array([0, 1, 6, 7, 8, 9, 10])
"""Segments made unit vectors: thighs (abduction), upper arms, forearms, neck (then ``up``)."""
_TABLE_ORDER: Final = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 10])
"""Columns of [knee, hip, abduction, ankle, elbow, neck, shoulder] in :func:`_angle_table`'s
order (the shoulders before the neck)."""


def _angle_table(
    joints: FloatArray, left: FloatArray, up: FloatArray, forward: FloatArray
) -> FloatArray:
    """(S, 13) angles in degrees: each of :data:`_SIDED_ANGLES` left then right, then the neck.

    joints: component-major (3, S, 25); left, up, forward: (3, S) (:func:`_body_frame`).
    Angles of the same kind are computed together (left and right, knees with ankles, hips
    with shoulders, elbows with the neck): each is the same operations as alone.
    """
    left_, up_, forward_ = left[:, :, None], up[:, :, None], forward[:, :, None]
    segment = joints[:, :, _SEGMENT_DISTAL] - joints[:, :, _SEGMENT_PROXIMAL]  # (3, S, 11)
    # Knee flexion swings the shank backwards: positive about the person's left axis; the foot
    # points forward from the shank: positive about the person's right axis. (S, 4) signed
    # angles from (thigh, shank) to (shank, foot).
    first, second = segment[:, :, 0:4], segment[:, :, 2:6]
    axis = np.repeat(left_, 4, axis=2)
    np.negative(axis[:, :, 2:], out=axis[:, :, 2:])  # the right axis (np.negative: NaN bits too)
    bend = np.degrees(np.arctan2(_dot(_cross(first, second), axis), _dot(first, second)))
    # Hip: thigh against the trunk's down axis, flexion forward. Shoulder extension: the arm
    # behind the trunk while below shoulder height.
    limbs = segment[:, :, _LIMBS]
    ahead = _dot(limbs, forward_)
    np.negative(ahead[:, 2:], out=ahead[:, 2:])  # the arms: how far behind
    below = _dot(limbs, -up_)
    swing = np.degrees(np.arctan2(ahead, below))
    units = _unit_major(np.concatenate([segment[:, :, _TO_UNIT], up_], axis=2))  # (3, S, 8)
    # Abduction: how far the thigh leaves the sagittal plane (outwards positive).
    outwards = _SIDE_SIGN * _dot(units[:, :, 0:2], left_)
    abduction = np.degrees(np.arcsin(np.clip(outwards, -1.0, 1.0)))
    # Elbows (upper arm to forearm) and the neck (up to the neck), unsigned.
    cos = _dot(units[:, :, [2, 3, 7]], units[:, :, [4, 5, 6]])
    unsigned = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    shoulder = np.where(below[:, 2:4] > 0, swing[:, 2:4], 0.0)
    out: FloatArray = np.concatenate(
        [bend[:, 0:2], swing[:, 0:2], abduction, bend[:, 2:4], unsigned, shoulder], axis=1
    )[:, _TABLE_ORDER]
    return out


def joint_angles(views: npt.ArrayLike) -> dict[str, tuple[FloatArray, int]]:
    """The range-of-motion angles of each view (degrees) and the joint each one lands on.

    Args:
        views: (S, 25, 3) joints, metres, world frame.

    Returns:
        ``name_side`` → ((S,) angles in degrees, NaN where unknown; distal joint index).
    """
    joints = np.ascontiguousarray(np.asarray(views, dtype=np.float64).transpose(2, 0, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        table = _angle_table(joints, *_body_frame(joints))
    out: dict[str, tuple[FloatArray, int]] = {}
    for side_index, side in enumerate(("left", "right")):
        for k, (name, distal) in enumerate(_SIDED_ANGLES):
            out[f"{name}_{side}"] = (table[:, 2 * k + side_index], int(distal[side_index]))
    out["neck_flexion"] = (table[:, 12], int(J.HEAD))
    return out


def rom_factors_and_forward(
    views: npt.ArrayLike, scale_deg: float
) -> tuple[FloatArray, FloatArray]:
    """:func:`range_of_motion_factors` and the views' ``forward`` axes (:func:`body_frame`).

    Runs the compiled kernel when :func:`skelfuse.fusion.kernels.enabled` (the same bits); the
    numpy code below is the reference.
    """
    joints = np.asarray(views, dtype=np.float64)
    if kernels.enabled():
        return kernels.rom_factors_and_forward(joints, scale_deg, _ANGLE_LOW, _ANGLE_HIGH)
    major = np.ascontiguousarray(joints.transpose(2, 0, 1))  # fancy indexing is faster on it
    with np.errstate(invalid="ignore", divide="ignore"):
        left, up, forward = _body_frame(major)
        angles = _angle_table(major, left, up, forward)
    excess = np.maximum(_ANGLE_LOW - angles, 0.0) + np.maximum(angles - _ANGLE_HIGH, 0.0)
    factors = np.where(np.isfinite(excess), np.exp(-excess / scale_deg), 1.0)
    out = np.ones(joints.shape[:2])
    out[:, _SINGLE_JOINTS] = factors[:, _SINGLE_COLUMNS]
    # The knee gets hip flexion × hip abduction (1 · a · b as a running product: the same bits).
    out[:, J.KNEE_LEFT] = factors[:, _KNEE_COLUMNS[0]] * factors[:, _KNEE_COLUMNS[2]]
    out[:, J.KNEE_RIGHT] = factors[:, _KNEE_COLUMNS[1]] * factors[:, _KNEE_COLUMNS[3]]
    return out, forward.T.copy()


def facing_direction(joints: npt.ArrayLike) -> FloatArray:
    """Horizontal unit vector the person faces (3,), from one skeleton; NaN if unknown.

    Args:
        joints: (25, 3) joints, metres, world frame (+Y up).
    """
    result: FloatArray = facing_directions(np.asarray(joints, dtype=np.float64)[None])[0]
    return result


def facing_directions(skeletons: npt.ArrayLike) -> FloatArray:
    """:func:`facing_direction` of each of P skeletons (P, 25, 3) at once: (P, 3).

    Runs the compiled kernel when :func:`skelfuse.fusion.kernels.enabled` (the same bits)."""
    if kernels.enabled():
        return kernels_stages.facing_directions(np.asarray(skeletons, dtype=np.float64))
    _, _, forward = body_frame(skeletons)
    return facings_of_forward(forward)


def facings_of_forward(forward: FloatArray) -> FloatArray:
    """Horizontal unit facings (P, 3) from :func:`body_frame` forward axes (P, 3); NaN rows
    where unknown (the body's forward axis close to vertical, or missing)."""
    horizontal = forward * HORIZONTAL
    # np.vecdot is the dot product np.linalg.norm uses on one vector (the same bits).
    norm = np.sqrt(np.vecdot(horizontal, horizontal))
    ok = np.isfinite(horizontal).all(-1) & ~(norm < 1e-6)
    with np.errstate(invalid="ignore", divide="ignore"):
        result: FloatArray = np.where(ok[:, None], horizontal / norm[:, None], np.nan)
    return result


def align_yaw(views: npt.ArrayLike, target_facing: npt.ArrayLike, max_deg: float) -> FloatArray:
    """Turn each view about the vertical through its SpineBase to face ``target_facing``.

    Corrects each sensor's bias of turning the skeleton towards itself (conventions.md §5)
    once the person's true facing is known from the views the person faces most directly.

    Args:
        views: (S, 25, 3) joints, metres, world frame (labels already corrected).
        target_facing: (3,) horizontal unit vector (NaN: nothing is changed).
        max_deg: larger corrections are not applied (the view is left as it is).

    Returns:
        (S, 25, 3) float64 turned views.
    """
    joints = np.array(views, dtype=np.float64, copy=True)
    target = np.asarray(target_facing, dtype=np.float64)
    if not np.isfinite(target).all():
        return joints
    for i in range(joints.shape[0]):
        own = facing_direction(joints[i])
        pivot = joints[i, J.SPINE_BASE]
        if not (np.isfinite(own).all() and np.isfinite(pivot).all()):
            continue
        # Signed yaw from own to target about +Y (heading atan2(x, z) as in the simulator).
        angle = math.atan2(target[0], target[2]) - math.atan2(own[0], own[2])
        angle = (angle + math.pi) % (2 * math.pi) - math.pi
        if abs(math.degrees(angle)) > max_deg:
            continue
        c, s_ = math.cos(angle), math.sin(angle)
        rotation = np.array([[c, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c]])
        joints[i] = (joints[i] - pivot) @ rotation.T + pivot
    return joints


def corrected_yaw(joints: FloatArray, cosines: FloatArray, max_deg: float) -> FloatArray:
    """One person's views turned to the facing of the views seen most squarely.

    The person's facing is the mean of each view's own facing weighted by how squarely its
    sensor sees the person (least turned by the sensor's bias), then every view is turned to it
    (``correct_view_yaw``).

    Args:
        joints: (S, 25, 3) one person's views, metres, world frame, labels corrected.
        cosines: (S,) each view's facing cosine (:func:`~skelfuse.fusion.confidence.
            facing_cosines`), NaN where unknown.
        max_deg: larger corrections are not applied.

    Returns:
        (S, 25, 3) float64.
    """
    frontal = np.nan_to_num(np.abs(cosines), nan=0.5) ** 4 + 1e-6
    own = np.stack([facing_direction(v) for v in joints])
    usable = np.isfinite(own).all(axis=1)
    if usable.any():
        mean = (frontal[usable, None] * own[usable]).sum(axis=0)
        norm = float(np.linalg.norm(mean))
        if norm > 1e-6:
            return align_yaw(joints, mean / norm, max_deg)
    return joints
