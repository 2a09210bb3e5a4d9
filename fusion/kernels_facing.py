"""The confidence's facing terms as loops, for compiled kernels.

:func:`cosines_loop` and :func:`facing_factors_loop` are the confidence's facing cosines and
factors written as scalar code compiled with numba: sums over three components as numpy's,
from 0, one after the other; ``array ** exponent`` with numpy's fast paths.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import jit

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


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
