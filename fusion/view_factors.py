"""Each view's factor from where its sensor stands: how frontally the person faces it.

A Kinect v2 is best when the person faces it: it assumes the person faces it and turns the
skeleton towards itself by about half the person's yaw relative to it (conventions.md §5).
``facing = floor + (1 − floor)·|cos θ|^p``, θ the angle between the person's forward direction
and the direction to the sensor (1 facing it or with its back to it, ``floor`` side-on), times
``back_factor`` from behind (:func:`facing_factors`).

:func:`view_factors` is one loop compiled with numba (:func:`view_factor_loop`, the facing
factor from :func:`facing_factors_loop`), each view with its sensor's facing model
(:func:`~skelfuse.fusion.confidence.sensor_terms`); ``pow`` is the C library's. :func:`warm_up`
compiles the loops (or loads numba's cache) at start, so no frame waits for a compilation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.confidence import sensor_terms
from skelfuse.fusion.priors import SensorPrior
from skelfuse.fusion.settings import FusionSettings
from skelfuse.jit import jit, plain

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


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


def facing_cosines(
    facing: npt.ArrayLike, body_position: npt.ArrayLike, sensor_positions: npt.ArrayLike
) -> FloatArray:
    """cos θ per view: θ between the person's facing and the horizontal direction to the sensor.

    Args:
        facing: (..., 3) horizontal unit vectors (NaN if unknown), e.g. (3,) one person's.
        body_position: (..., 3) a point on the person (SpineBase), metres, world.
        sensor_positions: (..., 3) sensor positions, metres, world (NaN if unknown), e.g.
            (S, 3); the three broadcast together.

    Returns:
        (...) float64 in [−1, 1], the broadcast shape without its last axis; NaN where unknown.
    """
    facings = np.asarray(facing, dtype=np.float64)
    bodies = np.asarray(body_position, dtype=np.float64)
    sensors = np.asarray(sensor_positions, dtype=np.float64)
    shape = np.broadcast_shapes(facings.shape, bodies.shape, sensors.shape)
    one, at, to = (  # (broadcast only when needed: µs a call)
        plain((a if a.shape == shape else np.broadcast_to(a, shape)).reshape(-1, 3))
        for a in (facings, bodies, sensors)
    )
    out = np.empty(shape[:-1])
    cosines_loop(one, at, to, out.reshape(-1))
    return out


def facing_factors(
    cosines: npt.ArrayLike, power: float, floor: float, back_factor: float = 1.0
) -> FloatArray:
    """Facing term per view, in (0, 1] with the shape of ``cosines``; 1 where the facing is
    unknown (NaN).

    ``floor + (1 − floor)·|cos θ|^power``, times ``back_factor`` when the sensor is behind the
    person (cos θ < 0). A sensor's own yaw bias grows with how far the person is turned from
    *its axis*, front or back (a view from behind, once its labels are swapped back by
    :mod:`fusion.mirror`, is fitted as a front view: conventions.md §5), so side views are the
    least trusted; a back view also hides the arms in front of the body, hence ``back_factor``.
    """
    cos = plain(cosines)
    out = np.empty(cos.shape)
    facing_factors_loop(
        cos.reshape(-1), float(power), float(floor), float(back_factor), out.reshape(-1)
    )
    return out


def view_factors(
    cosines: FloatArray,
    settings: FusionSettings,
    priors: Sequence[SensorPrior] | None = None,
) -> FloatArray:
    """Each view's facing factor, each with its sensor type's facing model.

    Args:
        cosines: (N,) :func:`facing_cosines` of each view (NaN: unknown, factor 1).
        settings: the facing model of sensors without a prior of their own.
        priors: (N,) each view's sensor prior (its facing model), or None: the settings'.

    Returns:
        (N,) float64 in (0, 1].
    """
    cos = plain(cosines)
    terms, of_view = sensor_terms(settings, priors, len(cos))
    out = np.empty(len(cos))
    view_factor_loop(cos, terms, plain(of_view, np.intp), out)
    return out


@jit
def view_factor_loop(
    cosines: FloatArray, terms: FloatArray, of_view: IntArray, out: FloatArray
) -> None:
    """Fill ``out`` (N,) with each view's facing factor (:func:`view_factors`).

    cosines: (N,) facing cosines (NaN: factor 1); terms, of_view: :func:`sensor_terms` (the
    facing model in columns 6–8).
    """
    for v in range(len(out)):
        row = terms[of_view[v]]
        facing_factors_loop(cosines[v : v + 1], row[6], row[7], row[8], out[v : v + 1])


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loops now."""
    views = np.zeros((2, 25, 3))
    view_factors(np.zeros(2), FusionSettings())
    facing_factors(facing_cosines(views[0], views[1], views[0]), 2.0, 0.1, 0.5)
