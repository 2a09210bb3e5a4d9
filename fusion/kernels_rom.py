"""The range-of-motion factors and body frame as one loop per view, for a compiled kernel.

:func:`rom_loop` is :func:`skelfuse.fusion.anatomy.rom_factors_and_forward` written as scalar
code: :mod:`skelfuse.fusion.kernels` compiles it with numba (the numpy version costs ~70 small
array operations per call, whatever the number of views). Every value is computed with the
same IEEE operations in the same order as the numpy version, so the results are the same bits:
dot products as (a₀b₀ + a₁b₁) + a₂b₂, cross products component by component as ``np.cross``,
``np.degrees`` as ``x · (180 / π)``, ``np.clip`` and ``np.maximum`` passing NaN through, and
``atan2``/``asin``/``acos``/``exp`` from the C library, as numpy's own loops call them on a
machine without AVX-512 (numpy's AVX-512 SVML loops may differ in the last bit: the tests
compare both paths on the machine they run on).

Imported only by :mod:`skelfuse.fusion.kernels` when the kernels run; without numba
:func:`~skelfuse.fusion.kernels_jit.jit` leaves the functions plain Python (slow, same results).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import jit, jit_inline
from skelfuse.protocol.skeleton import JointId as J

FloatArray = npt.NDArray[np.float64]

_RAD2DEG = 180.0 / math.pi
"""``np.degrees`` multiplies by this constant (numpy's ``npy_rad2deg``)."""

# Joint indices as plain ints (numba types globals of these as integer constants).
_SB, _SS = int(J.SPINE_BASE), int(J.SPINE_SHOULDER)
_HL, _HR, _SL, _SR = int(J.HIP_LEFT), int(J.HIP_RIGHT), int(J.SHOULDER_LEFT), int(J.SHOULDER_RIGHT)
_KL, _KR, _AL, _AR = int(J.KNEE_LEFT), int(J.KNEE_RIGHT), int(J.ANKLE_LEFT), int(J.ANKLE_RIGHT)
_FL, _FR, _EL, _ER = int(J.FOOT_LEFT), int(J.FOOT_RIGHT), int(J.ELBOW_LEFT), int(J.ELBOW_RIGHT)
_WL, _WR, _NK, _HD = int(J.WRIST_LEFT), int(J.WRIST_RIGHT), int(J.NECK), int(J.HEAD)


@jit
def _clip_unit(x: float) -> float:
    """``np.clip(x, -1, 1)`` (NaN stays NaN)."""
    if x < -1.0:
        return -1.0
    if x > 1.0:
        return 1.0
    return x


@jit
def _positive(x: float) -> float:
    """``np.maximum(x, 0.0)`` (NaN stays NaN; −0 or +0 give exp(0) alike downstream)."""
    if x >= 0.0 or x != x:
        return x
    return 0.0


@jit
def _factor(angle: float, low: float, high: float, scale_deg: float) -> float:
    """One angle's range-of-motion factor: exp(−excess / scale), 1 where unknown."""
    excess = _positive(low - angle) + _positive(angle - high)
    if math.isfinite(excess):
        return math.exp(-excess / scale_deg)
    return 1.0


@jit_inline
def body_frame(
    v: FloatArray,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """``anatomy._body_frame`` of one view ``v`` (25, 3): the unit up axis (SpineBase →
    SpineShoulder), the unit left axis (hips + shoulders, each where finite, made normal to
    up) and forward = left × up, as ``(u0, u1, u2, l0, l1, l2, f0, f1, f2)``; NaN where the
    trunk is unknown. Numba inlines it into :func:`rom_loop` and
    :func:`skelfuse.fusion.kernels_facing.facing_loop`: the same operations in the same order.
    numba's disk cache checks only the caller's own file: after editing this function, delete
    ``fusion/__pycache__/kernels_facing.*.nb?`` (or touch kernels_facing.py) on a machine
    that has run the kernels, or facing_loop keeps the old body (CI starts without a cache).
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
def rom_loop(
    views: FloatArray,
    scale_deg: float,
    low: FloatArray,
    high: FloatArray,
    factors: FloatArray,
    forward: FloatArray,
) -> None:
    """Fill ``factors`` (M, 25) and ``forward`` (M, 3) for ``views`` (M, 25, 3).

    ``low``, ``high``: (13,) the angle limits in :func:`~skelfuse.fusion.anatomy._angle_table`'s
    column order (degrees). ``factors`` must be all ones on entry (joints without an angle).
    """
    seg = np.empty((11, 3))
    unit = np.empty((8, 3))
    angle = np.empty(13)
    distal = (_KL, _KR, _AL, _AR, _FL, _FR, _EL, _ER, _WL, _WR, _HD)
    proximal = (_HL, _HR, _KL, _KR, _AL, _AR, _SL, _SR, _EL, _ER, _NK)
    for m in range(views.shape[0]):
        v = views[m]
        u0, u1, u2, l0, l1, l2, f0, f1, f2 = body_frame(v)
        forward[m, 0], forward[m, 1], forward[m, 2] = f0, f1, f2
        # Segments, distal − proximal (anatomy._SEGMENT_DISTAL / _SEGMENT_PROXIMAL).
        for k in range(11):
            for c in range(3):
                seg[k, c] = v[distal[k], c] - v[proximal[k], c]
        # Knee (thigh → shank about left) and ankle (shank → foot about right): bends 0..3.
        for i in range(4):
            a, b = seg[i], seg[i + 2]
            x0, x1, x2 = (
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            )
            sign = 1.0 if i < 2 else -1.0  # the left axis, then the right (exact negation)
            axis = (x0 * (sign * l0) + x1 * (sign * l1)) + x2 * (sign * l2)
            along = (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
            column = i if i < 2 else i + 4  # knees 0, 1; ankles 6, 7
            angle[column] = math.atan2(axis, along) * _RAD2DEG
        # Hip flexion (thighs, segments 0, 1) and shoulder extension (upper arms, 6, 7).
        for i in range(4):
            k = i if i < 2 else i + 4
            a = seg[k]
            ahead = (a[0] * f0 + a[1] * f1) + a[2] * f2
            if i >= 2:
                ahead = -ahead
            below = (a[0] * -u0 + a[1] * -u1) + a[2] * -u2
            swing = math.atan2(ahead, below) * _RAD2DEG
            if i < 2:
                angle[2 + i] = swing
            else:
                angle[10 + i - 2] = swing if below > 0 else 0.0
        # Unit segments: thighs, upper arms, forearms, neck, then up again (anatomy._TO_UNIT).
        for j in range(7):
            k = (0, 1, 6, 7, 8, 9, 10)[j]
            norm = math.sqrt(
                (seg[k, 0] * seg[k, 0] + seg[k, 1] * seg[k, 1]) + seg[k, 2] * seg[k, 2]
            )
            for c in range(3):
                unit[j, c] = seg[k, c] / norm
        norm = math.sqrt((u0 * u0 + u1 * u1) + u2 * u2)
        unit[7, 0], unit[7, 1], unit[7, 2] = u0 / norm, u1 / norm, u2 / norm
        # Hip abduction: the thigh out of the sagittal plane (right side mirrored).
        for i in range(2):
            out = (unit[i, 0] * l0 + unit[i, 1] * l1) + unit[i, 2] * l2
            if i == 1:
                out = -out
            angle[4 + i] = math.asin(_clip_unit(out)) * _RAD2DEG
        # Elbows (upper arm · forearm) and the neck (up · neck), unsigned.
        for i in range(3):
            a, b = unit[(2, 3, 7)[i]], unit[(4, 5, 6)[i]]
            cos = (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
            angle[(8, 9, 12)[i]] = math.acos(_clip_unit(cos)) * _RAD2DEG
        # Factors onto the joints (anatomy._SINGLE_JOINTS, the knees as running products).
        row = factors[m]
        row[_AL] = _factor(angle[0], low[0], high[0], scale_deg)
        row[_AR] = _factor(angle[1], low[1], high[1], scale_deg)
        row[_FL] = _factor(angle[6], low[6], high[6], scale_deg)
        row[_FR] = _factor(angle[7], low[7], high[7], scale_deg)
        row[_WL] = _factor(angle[8], low[8], high[8], scale_deg)
        row[_WR] = _factor(angle[9], low[9], high[9], scale_deg)
        row[_EL] = _factor(angle[10], low[10], high[10], scale_deg)
        row[_ER] = _factor(angle[11], low[11], high[11], scale_deg)
        row[_HD] = _factor(angle[12], low[12], high[12], scale_deg)
        row[_KL] = _factor(angle[2], low[2], high[2], scale_deg) * _factor(
            angle[4], low[4], high[4], scale_deg
        )
        row[_KR] = _factor(angle[3], low[3], high[3], scale_deg) * _factor(
            angle[5], low[5], high[5], scale_deg
        )
