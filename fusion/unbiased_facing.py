"""Each person's facing with every sensor's yaw bias taken out (``mirror.unbiased_facing``).

A Kinect turns the body it reports towards itself by ``lean`` × the person's yaw θ to it
(clamped to ±90°; the simulator's ``facing_bias``): a view's own facing is at φ = θ − lean ×
clamp(θ) from its sensor. A view the sensor mirrored was fitted to the back, at the apparent yaw
θ ∓ 180°, and turned by that; swapped back, its facing is reversed again. A fused skeleton
inherits these turns: a person seen side-on by two sensors looks turned by 40–60° (the crossing
scenario's turns), enough to put a side sensor behind them and to keep that view's old labels
after the sensor flips. Inverting each view's turn under the labelling chosen, and averaging the
unit vectors, gives the facing back.

One loop compiled with numba (:func:`unbiased_loop`): ``%`` as numpy's floating remainder (the
divisor's sign), the sign of 0 as 0, sums over a person's views from 0 view after view,
``atan2`` / ``sin`` / ``cos`` from the C library.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import facing_directions
from skelfuse.fusion.mirror_scores import slots
from skelfuse.jit import jit, plain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]

_PI = math.pi


def unbiased_facings(
    joints: FloatArray,
    sensor_positions: FloatArray,
    mirrored: BoolArray,
    counts: Sequence[int],
    lean: float,
    own: FloatArray | None = None,
) -> FloatArray:
    """(P, 3) each person's horizontal facing from its labelled views, each sensor's yaw bias
    taken out; NaN rows where no view gives one.

    Args:
        joints: (N, 25, 3) every person's views, labels corrected; metres, world.
        sensor_positions: (N, 3) metres, world (NaN rows: unknown).
        mirrored: (N,) whether each view was swapped back (the sensor reported it mirrored).
        counts: views per person.
        lean: the share of its yaw a sensor turns a body towards itself, in [0, 1).
        own: (N, 3) each view's :func:`~skelfuse.fusion.anatomy.facing_directions` as
            labelled, when the caller has them (None: computed here).

    Returns:
        (P, 3) horizontal unit vectors (y = 0), NaN where unknown.

    Raises:
        ValueError: when ``lean`` is not in [0, 1).
    """
    check_lean(lean)
    points = plain(joints)
    facings = facing_directions(points) if own is None else plain(own)
    out = np.empty((len(counts), 3))
    unbiased_loop(
        np.ascontiguousarray(points[:, 0]),
        plain(sensor_positions),
        facings,
        plain(mirrored, np.bool_),
        plain(slots(tuple(counts)).starts, np.intp),
        float(lean),
        out,
    )
    return out


def check_lean(lean: float) -> None:
    """Raises ValueError when ``lean`` (a share of the yaw) is not in [0, 1)."""
    if not 0.0 <= lean < 1.0:
        raise ValueError(f"lean must be in [0, 1), got {lean}")


@jit
def _wrap(angle: float) -> float:
    """An angle (radians) wrapped to [−π, π): (angle + π) mod 2π − π."""
    return (angle + _PI) % (2 * _PI) - _PI


@jit
def _sign(x: float) -> float:
    """±1, 0 at ±0, NaN stays NaN (``np.sign``)."""
    if x > 0:
        return 1.0
    if x < 0:
        return -1.0
    if x == 0:
        return 0.0
    return x


@jit
def _unturn(phi: float, lean: float) -> float:
    """The yaw θ whose view is at φ = θ − lean × clamp(θ, ±90°) (monotonic: one θ per φ)."""
    knee = (1.0 - lean) * (_PI / 2)
    if abs(phi) <= knee:
        return phi / (1.0 - lean)
    return phi + lean * (_PI / 2) * _sign(phi)


@jit
def unbiased_loop(
    origins: FloatArray,
    sensor_positions: FloatArray,
    own: FloatArray,
    mirrored: BoolArray,
    starts: IntArray,
    lean: float,
    out: FloatArray,
) -> None:
    """Fill ``out`` (P, 3) with each person's unbiased facing (NaN rows where unknown).

    origins: (N, 3) each view's SpineBase; sensor_positions: (N, 3); own: (N, 3) each view's
    horizontal unit facing as labelled (NaN: unknown); mirrored: (N,) the labelling chosen;
    starts: (P + 1,) each person's first view, then N; lean: in [0, 1).
    """
    for p in range(len(starts) - 1):
        m0 = m1 = m2 = 0.0
        for v in range(starts[p], starts[p + 1]):
            flipped = mirrored[v]
            sensor_angle = math.atan2(
                sensor_positions[v, 0] - origins[v, 0], sensor_positions[v, 2] - origins[v, 2]
            )
            phi = _wrap(sensor_angle - math.atan2(own[v, 0], own[v, 2]))
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


def warm_up() -> None:
    """Compile (or load from numba's cache) the loop now, for the argument types every call
    passes (:func:`~skelfuse.jit.plain`), so no frame waits for it."""
    views = np.zeros((2, 25, 3))
    unbiased_facings(views, np.ones((2, 3)), np.zeros(2, bool), [2], 0.5)
