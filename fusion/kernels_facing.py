"""Facing loops, for compiled kernels: each person's facing with the sensors' yaw bias taken
out, the walking check, and the confidence's facing terms.

:func:`unbiased_loop` is :func:`skelfuse.fusion.labels.unbiased_facings`,
:func:`backwards_loop` the first half of :func:`skelfuse.fusion.labels.walking_backwards`,
:func:`cosines_loop` and :func:`facing_factors_loop` the confidence's facing terms, written as
scalar code compiled with numba: dot products as (a₀b₀ + a₁b₁) + a₂b₂, ``%`` as numpy's
floating remainder (the divisor's sign, as Python's), ``np.sign`` 0 at 0, sums over a person's
views from 0 view after view, ``atan2``/``sin``/``cos`` from the C library.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import jit

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

_PI = math.pi


@jit
def _wrap(angle: float) -> float:
    """``labels._wrap``: (angle + π) mod 2π − π."""
    return (angle + _PI) % (2 * _PI) - _PI


@jit
def _sign(x: float) -> float:
    """``np.sign``: ±1, 0 at ±0, NaN stays NaN."""
    if x > 0:
        return 1.0
    if x < 0:
        return -1.0
    if x == 0:
        return 0.0
    return x


@jit
def _unturn(phi: float, lean: float) -> float:
    """``labels._unturn`` of one angle."""
    knee = (1.0 - lean) * (_PI / 2)
    if abs(phi) <= knee:
        return phi / (1.0 - lean)
    return phi + lean * (_PI / 2) * _sign(phi)


@jit
def unbiased_loop(
    origins: FloatArray,
    sensor_positions: FloatArray,
    forward: FloatArray,
    mirrored: BoolArray,
    starts: IntArray,
    lean: float,
    out: FloatArray,
) -> None:
    """Fill ``out`` (P, 3) with each person's unbiased facing (NaN rows where unknown).

    origins: (N, 3) each view's SpineBase; sensor_positions: (N, 3); forward: (N, 2, 3) each
    view's forward axis as reported and swapped; mirrored: (N,) the labelling chosen;
    starts: (P + 1,) each person's first view, then N; lean: in [0, 1).
    """
    for p in range(len(starts) - 1):
        m0 = m1 = m2 = 0.0
        for v in range(starts[p], starts[p + 1]):
            flipped = mirrored[v]
            axis = forward[v, 1 if flipped else 0]
            h0, h1, h2 = axis[0] * 1.0, axis[1] * 0.0, axis[2] * 1.0
            norm = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
            ok = math.isfinite(h0) and math.isfinite(h1) and math.isfinite(h2)
            if ok and not norm < 1e-6:
                own0, own2 = h0 / norm, h2 / norm
            else:
                own0 = own2 = math.nan
            sensor_angle = math.atan2(
                sensor_positions[v, 0] - origins[v, 0], sensor_positions[v, 2] - origins[v, 2]
            )
            phi = _wrap(sensor_angle - math.atan2(own0, own2))
            if flipped:  # turned at its apparent yaw (facing reversed): invert there, turn back
                phi = _wrap(phi - _PI)
            theta = _unturn(phi, lean)
            if flipped:
                theta = _wrap(theta + _PI)
            angle = sensor_angle - theta
            if math.isfinite(angle):
                m0 += math.sin(angle)
                m1 += 0.0
                m2 += math.cos(angle)
        norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if norm > 1e-6:
            out[p, 0], out[p, 1], out[p, 2] = m0 / norm, m1 / norm, m2 / norm
        else:
            out[p, 0] = out[p, 1] = out[p, 2] = math.nan


@jit
def cosines_loop(
    facings: FloatArray, bodies: FloatArray, sensor_positions: FloatArray, out: FloatArray
) -> None:
    """Fill ``out`` (N,) with ``confidence.facing_cosines`` of each view: its person's facing
    (N, 3) against the horizontal unit direction from where it stands (N, 3) to its sensor
    (N, 3). Sums over three components as numpy's: from 0, one after the other."""
    for v in range(len(out)):
        t0 = (sensor_positions[v, 0] - bodies[v, 0]) * 1.0
        t1 = (sensor_positions[v, 1] - bodies[v, 1]) * 0.0
        t2 = (sensor_positions[v, 2] - bodies[v, 2]) * 1.0
        norm = math.sqrt(0.0 + t0 * t0 + t1 * t1 + t2 * t2)
        out[v] = (
            0.0 + t0 / norm * facings[v, 0] + t1 / norm * facings[v, 1] + t2 / norm * facings[v, 2]
        )


@jit
def _power(x: float, exponent: float) -> float:
    """``array ** exponent`` as numpy computes it for a scalar exponent: its fast paths for 2,
    0.5, 1, −1 and 0 (square, sqrt, copy, reciprocal, ones), else the C library's pow."""
    if exponent == 2.0:
        return x * x
    if exponent == 0.5:
        return math.sqrt(x)
    if exponent == 1.0:
        return x
    if exponent == -1.0:
        return 1.0 / x
    if exponent == 0.0:
        return 1.0
    result: float = x**exponent
    return result


@jit
def facing_factors_loop(
    cosines: FloatArray, power: float, floor: float, back_factor: float, out: FloatArray
) -> None:
    """Fill ``out`` (N,) with ``confidence.facing_factors``: ``floor + (1 − floor)·|cos|^power``
    (× ``back_factor`` behind the person), 1 where the cosine is unknown."""
    for v in range(len(out)):
        cos = cosines[v]
        if not math.isfinite(cos):
            out[v] = 1.0
            continue
        clipped = -1.0 if cos < -1.0 else (1.0 if cos > 1.0 else cos)
        value = floor + (1.0 - floor) * _power(abs(clipped), power)
        out[v] = value * back_factor if cos < 0 else value


@jit
def backwards_loop(
    velocities: FloatArray, facings: FloatArray, min_speed: float, out: BoolArray
) -> None:
    """Fill ``out`` (P,) with whether each person walks backwards now, as
    :func:`skelfuse.fusion.labels.walking_backwards` decides it before its timing: at least
    ``min_speed`` (m/s) with a finite facing (P, 3) against the velocity (P, 3) by more than
    half the speed (``(a₀b₀ + a₁b₁) + a₂b₂`` as there, on Python floats)."""
    for p in range(len(out)):
        v0, v1, v2 = velocities[p, 0], velocities[p, 1], velocities[p, 2]
        speed = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        backwards = False
        if speed >= min_speed:
            f0, f1, f2 = facings[p, 0], facings[p, 1], facings[p, 2]
            finite = math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)
            backwards = finite and f0 * v0 + f1 * v1 + f2 * v2 < -0.5 * speed
        out[p] = backwards
