"""The body's own geometry: kinematic chain order, body frame, joint angles, facing, yaw.

Pure functions on arrays of joints, (S, 25, 3) or (25, 3), metres, world frame (+Y up); NaN
where a joint is unknown. The body frame, the angles, their range-of-motion factors and the
facings are loops over views compiled with numba (:func:`warm_up` compiles them ahead).
:mod:`skelfuse.fusion.confidence` turns the angles into confidence terms; its docstring gives
the sources of :data:`ROM_LIMITS_DEG`.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.jit import jit, jit_inline, plain
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
"""Keeps the horizontal components of a vector (…, 3)."""


def unit(v: FloatArray) -> FloatArray:
    """Unit vectors along the last axis (…, 3); NaN where a vector is zero or unknown."""
    with np.errstate(invalid="ignore", divide="ignore"):
        result: FloatArray = v / np.sqrt((v * v).sum(-1, keepdims=True))  # np.linalg.norm's bits
    return result


# The loops keep numpy's conventions: dot products as (a₀b₀ + a₁b₁) + a₂b₂, cross products as
# ``np.cross``, clips passing NaN through, atan2 / asin / acos / exp from the C library.
_RAD2DEG: Final = 180.0 / math.pi  # what np.degrees multiplies by (numpy's npy_rad2deg)

# Joint indices as plain ints (numba types globals of these as integer constants).
_SB, _SS = int(J.SPINE_BASE), int(J.SPINE_SHOULDER)
_HL, _HR, _SL, _SR = int(J.HIP_LEFT), int(J.HIP_RIGHT), int(J.SHOULDER_LEFT), int(J.SHOULDER_RIGHT)
_KL, _KR, _AL, _AR = int(J.KNEE_LEFT), int(J.KNEE_RIGHT), int(J.ANKLE_LEFT), int(J.ANKLE_RIGHT)
_FL, _FR, _EL, _ER = int(J.FOOT_LEFT), int(J.FOOT_RIGHT), int(J.ELBOW_LEFT), int(J.ELBOW_RIGHT)
_WL, _WR, _NK, _HD = int(J.WRIST_LEFT), int(J.WRIST_RIGHT), int(J.NECK), int(J.HEAD)


@jit_inline
def body_axes(
    v: FloatArray,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """One view's own body axes from its labels, ``v`` (25, 3) metres, world frame: the unit up
    axis (SpineBase → SpineShoulder), the unit left axis (the hips' and the shoulders'
    left-minus-right vectors, each where finite, summed and made normal to up) and
    forward = left × up, as ``(u0, u1, u2, l0, l1, l2, f0, f1, f2)``; NaN where the trunk is
    unknown. Inlined into each loop by numba (numba's disk cache checks only the caller's
    file: a loop in another module that inlines this keeps a stale body after an edit here).
    """
    u0, u1, u2 = v[_SS, 0] - v[_SB, 0], v[_SS, 1] - v[_SB, 1], v[_SS, 2] - v[_SB, 2]
    norm = math.sqrt((u0 * u0 + u1 * u1) + u2 * u2)
    u0, u1, u2 = u0 / norm, u1 / norm, u2 / norm
    h0, h1, h2 = v[_HL, 0] - v[_HR, 0], v[_HL, 1] - v[_HR, 1], v[_HL, 2] - v[_HR, 2]
    s0, s1, s2 = v[_SL, 0] - v[_SR, 0], v[_SL, 1] - v[_SR, 1], v[_SL, 2] - v[_SR, 2]
    hips = math.isfinite(h0) and math.isfinite(h1) and math.isfinite(h2)
    shoulders = math.isfinite(s0) and math.isfinite(s1) and math.isfinite(s2)
    if hips or shoulders:
        l0 = (h0 if math.isfinite(h0) else 0.0) + (s0 if math.isfinite(s0) else 0.0)
        l1 = (h1 if math.isfinite(h1) else 0.0) + (s1 if math.isfinite(s1) else 0.0)
        l2 = (h2 if math.isfinite(h2) else 0.0) + (s2 if math.isfinite(s2) else 0.0)
    else:
        l0 = l1 = l2 = math.nan
    d = (l0 * u0 + l1 * u1) + l2 * u2
    l0, l1, l2 = l0 - d * u0, l1 - d * u1, l2 - d * u2
    norm = math.sqrt((l0 * l0 + l1 * l1) + l2 * l2)
    l0, l1, l2 = l0 / norm, l1 / norm, l2 / norm
    f0, f1, f2 = l1 * u2 - l2 * u1, l2 * u0 - l0 * u2, l0 * u1 - l1 * u0
    return u0, u1, u2, l0, l1, l2, f0, f1, f2


@jit
def _clip_unit(x: float) -> float:
    """``np.clip(x, -1, 1)`` (NaN stays NaN)."""
    if x < -1.0:
        return -1.0
    if x > 1.0:
        return 1.0
    return x


@jit
def _factor(angle: float, low: float, high: float, scale_deg: float) -> float:
    """One angle's range-of-motion factor: exp(−excess / scale), 1 where unknown (an excess of
    ±0 gives 1 alike)."""
    below, above = low - angle, angle - high
    excess = (below if below >= 0.0 or below != below else 0.0) + (
        above if above >= 0.0 or above != above else 0.0
    )
    if math.isfinite(excess):
        return math.exp(-excess / scale_deg)
    return 1.0


ROM_LIMITS_DEG: Final[dict[str, tuple[float, float]]] = {
    "knee_flexion": (-5.0, 145.0),
    "elbow_flexion": (0.0, 150.0),
    "hip_flexion": (-30.0, 130.0),
    "hip_abduction": (-30.0, 50.0),
    "shoulder_extension": (-180.0, 60.0),
    "ankle_shank_foot": (25.0, 150.0),
    "neck_flexion": (0.0, 70.0),
}
"""Anatomical range of each angle (degrees); sources and conventions in confidence.py."""


_SIDED_ANGLES: Final = (
    ("knee_flexion", (_AL, _AR)),
    ("hip_flexion", (_KL, _KR)),
    ("hip_abduction", (_KL, _KR)),
    ("ankle_shank_foot", (_FL, _FR)),
    ("elbow_flexion", (_WL, _WR)),
    ("shoulder_extension", (_EL, _ER)),
)
"""The per-side angles in the angle table's column order (left, right each; then the neck),
and the joints they land on."""


def _limits(bound: int) -> FloatArray:
    sided = [ROM_LIMITS_DEG[name][bound] for name, _ in _SIDED_ANGLES for _side in range(2)]
    return np.array([*sided, ROM_LIMITS_DEG["neck_flexion"][bound]])


ANGLE_LIMITS: Final = (_limits(0), _limits(1))
"""The angle table's limits, low and high (13,), degrees."""


@jit_inline
def _view_angles(v: FloatArray, axes: tuple[float, ...], seg: FloatArray, out: FloatArray) -> None:
    """Fill ``out`` (13,) with one view's angles (degrees, the table's column order) from its
    joints ``v`` (25, 3) and :func:`body_axes`; ``seg`` (19, 3) scratch: the segments, then
    the unit ones."""
    u0, u1, u2, l0, l1, l2, f0, f1, f2 = axes
    distal = (_KL, _KR, _AL, _AR, _FL, _FR, _EL, _ER, _WL, _WR, _HD)
    proximal = (_HL, _HR, _KL, _KR, _AL, _AR, _SL, _SR, _EL, _ER, _NK)
    for k in range(11):  # thighs, shanks, feet, upper arms, forearms, the neck: distal − proximal
        for c in range(3):
            seg[k, c] = v[distal[k], c] - v[proximal[k], c]
    # Knee (thigh → shank about the left axis), ankle (shank → foot about the right axis).
    for i in range(4):
        a, b = seg[i], seg[i + 2]
        x0, x1, x2 = a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]
        sign = 1.0 if i < 2 else -1.0  # the left axis, then the right (exact negation)
        axis = (x0 * (sign * l0) + x1 * (sign * l1)) + x2 * (sign * l2)
        along = (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
        out[i if i < 2 else i + 4] = math.atan2(axis, along) * _RAD2DEG  # knees 0, 1; ankles 6, 7
    # Hip flexion (thighs) and shoulder extension (upper arms, behind while below the shoulder).
    for i in range(4):
        a = seg[i if i < 2 else i + 4]
        ahead = (a[0] * f0 + a[1] * f1) + a[2] * f2
        below = (a[0] * -u0 + a[1] * -u1) + a[2] * -u2
        if i < 2:
            out[2 + i] = math.atan2(ahead, below) * _RAD2DEG
        else:
            out[8 + i] = math.atan2(-ahead, below) * _RAD2DEG if below > 0 else 0.0
    # Unit thighs, upper arms, forearms, neck, and up again.
    units = seg[11:]
    for j in range(7):
        a = seg[(0, 1, 6, 7, 8, 9, 10)[j]]
        norm = math.sqrt((a[0] * a[0] + a[1] * a[1]) + a[2] * a[2])
        units[j, 0], units[j, 1], units[j, 2] = a[0] / norm, a[1] / norm, a[2] / norm
    norm = math.sqrt((u0 * u0 + u1 * u1) + u2 * u2)
    units[7, 0], units[7, 1], units[7, 2] = u0 / norm, u1 / norm, u2 / norm
    for i in range(2):  # hip abduction: the thigh out of the sagittal plane, outwards positive
        outwards = (units[i, 0] * l0 + units[i, 1] * l1) + units[i, 2] * l2
        out[4 + i] = math.asin(_clip_unit(outwards if i == 0 else -outwards)) * _RAD2DEG
    for i in range(3):  # elbows (upper arm · forearm) and the neck (up · neck), unsigned
        a, b = units[(2, 3, 7)[i]], units[(4, 5, 6)[i]]
        cos = (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
        out[(8, 9, 12)[i]] = math.acos(_clip_unit(cos)) * _RAD2DEG


@jit
def rom_loop(
    views: FloatArray,
    limits: tuple[float, FloatArray, FloatArray],
    factors: FloatArray,
    forward: FloatArray,
    angles: FloatArray,
) -> None:
    """Fill ``factors`` (M, 25), ``forward`` (M, 3) and ``angles`` (M, 13) for ``views``
    (M, 25, 3): ``limits`` the scale (degrees outside the range for 1/e) and the angle limits
    low, high (13,). ``factors`` must be all ones on entry (joints without an angle)."""
    scale_deg, low, high = limits
    seg = np.empty((19, 3))
    single = (
        (0, _AL),
        (1, _AR),
        (6, _FL),
        (7, _FR),
        (8, _WL),
        (9, _WR),
        (10, _EL),
        (11, _ER),
        (12, _HD),
    )
    for m in range(views.shape[0]):
        axes = body_axes(views[m])
        forward[m, 0], forward[m, 1], forward[m, 2] = axes[6], axes[7], axes[8]
        angle = angles[m]
        _view_angles(views[m], axes, seg, angle)
        row = factors[m]
        for column, joint in single:
            row[joint] = _factor(angle[column], low[column], high[column], scale_deg)
        for column, joint in ((2, _KL), (3, _KR)):  # hip flexion × hip abduction on the knee
            row[joint] = _factor(angle[column], low[column], high[column], scale_deg) * _factor(
                angle[column + 2], low[column + 2], high[column + 2], scale_deg
            )


def _rom(views: npt.ArrayLike, scale_deg: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`rom_loop` of ``views`` (M, 25, 3): factors (M, 25), forward (M, 3), angles
    (M, 13)."""
    joints = plain(views)
    factors = np.ones(joints.shape[:2])
    forward = np.empty((joints.shape[0], 3))
    angles = np.empty((joints.shape[0], 13))
    rom_loop(joints, (float(scale_deg), *ANGLE_LIMITS), factors, forward, angles)
    return factors, forward, angles


def joint_angles(views: npt.ArrayLike) -> dict[str, tuple[FloatArray, int]]:
    """The range-of-motion angles of each view (degrees) and the joint each one lands on.

    Args:
        views: (S, 25, 3) joints, metres, world frame.

    Returns:
        ``name_side`` → ((S,) angles in degrees, NaN where unknown; distal joint index).
    """
    table = _rom(views, 1.0)[2]
    out: dict[str, tuple[FloatArray, int]] = {}
    for side_index, side in enumerate(("left", "right")):
        for k, (name, distal) in enumerate(_SIDED_ANGLES):
            out[f"{name}_{side}"] = (table[:, 2 * k + side_index], distal[side_index])
    out["neck_flexion"] = (table[:, 12], _HD)
    return out


def rom_factors_and_forward(
    views: npt.ArrayLike, scale_deg: float
) -> tuple[FloatArray, FloatArray]:
    """Each view's range-of-motion factors and its body's forward axis.

    Args:
        views: (M, 25, 3) joints, metres, world frame, NaN where unknown.
        scale_deg: degrees outside the range for a factor of 1/e.

    Returns:
        factors (M, 25) float64 in (0, 1] (1 where every angle landing on the joint is in range
        or unknown; the knees get hip flexion × hip abduction), forward (M, 3) unit vectors
        (NaN where the trunk is missing; :func:`body_axes`).
    """
    factors, forward, _ = _rom(views, scale_deg)
    return factors, forward


def facing_direction(joints: npt.ArrayLike) -> FloatArray:
    """Horizontal unit vector the person faces (3,), from one skeleton; NaN if unknown.

    Args:
        joints: (25, 3) joints, metres, world frame (+Y up).
    """
    result: FloatArray = facing_directions(np.asarray(joints, dtype=np.float64)[None])[0]
    return result


def facing_directions(skeletons: npt.ArrayLike) -> FloatArray:
    """:func:`facing_direction` of each of P skeletons (P, 25, 3) at once: (P, 3) horizontal unit
    vectors, NaN rows where unknown (the body's forward axis close to vertical, or missing)."""
    joints = plain(skeletons)
    out = np.empty((joints.shape[0], 3))
    facing_loop(joints, out)
    return out


@jit
def facing_loop(skeletons: FloatArray, out: FloatArray) -> None:
    """Fill ``out`` (P, 3) with the facings of ``skeletons`` (P, 25, 3): the forward axis of
    :func:`body_axes` made horizontal and unit (``np.vecdot`` order), NaN where its horizontal
    part is unknown or shorter than 1e-6."""
    for m in range(skeletons.shape[0]):
        f0, f1, f2 = body_axes(skeletons[m])[6:]
        h0, h1, h2 = f0 * 1.0, f1 * 0.0, f2 * 1.0
        norm = math.sqrt((h0 * h0 + h1 * h1) + h2 * h2)
        ok = math.isfinite(h0) and math.isfinite(h1) and math.isfinite(h2)
        if ok and not norm < 1e-6:
            out[m, 0], out[m, 1], out[m, 2] = h0 / norm, h1 / norm, h2 / norm
        else:
            out[m, 0] = out[m, 1] = out[m, 2] = math.nan


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loops now, for the argument types every
    call passes (:func:`~skelfuse.jit.plain`), so no frame waits for it."""
    views = np.zeros((2, 25, 3))
    rom_factors_and_forward(views, 15.0)
    facing_directions(views)
