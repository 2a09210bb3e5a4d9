"""Where each view's sensor stands relative to its person, and fusion with noise along the ray.

**Facing cosines** (:func:`facing_cosines`): cos θ between the person's forward direction and
the horizontal direction from the person to the view's sensor (1: the person faces it, −1:
turns its back on it); the online bone-length observation keeps the frontal views'
(fusion/bones.py), and :mod:`skelfuse.fusion.rig_errors` bins each view by where its sensor
stands. :func:`cosines_loop` is compiled with numba.

**Ray weighting** (:func:`ray_weighted_mean`: fusion that knows a view's noise is larger along
its sensor's viewing ray than across it). A camera that places a body from its apparent size
(the ``rgb`` sensor type, agent/sources/mono.py) knows well where a joint is across the image
and poorly how far it is: its variance along the ray from the sensor to the joint is ``ratio²``
times that across it (``SensorPrior.depth_noise_ratio``, fusion/priors.py). Treating each view
as a Gaussian with covariance ``σ²·(I + (ratio² − 1)·d·dᵀ)`` (d the unit ray) and its weight w
as 1/σ², the fused joint is the information-weighted mean::

    x = (Σ w·A)⁻¹ · Σ w·A·x_view,   A = I + (1/ratio² − 1)·d·dᵀ  (the inverse covariance shape)

With every ratio 1 this is :func:`fusion.weigh.weighted_mean`; with one view it is that view.
A second view from another direction then fixes the camera's depth while the camera keeps its
say across the image. Only persons with at least one such view are recomputed. Shapes as in
:mod:`fusion.weigh`: P persons, S views each (padded with NaN views of weight 0), J joints;
metres, world frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.priors import PRIORS
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


# --- Ray weighting: a view's noise larger along its sensor's viewing ray than across it ----------


_RATIO_OF: Final = {name: p.depth_noise_ratio for name, p in PRIORS.items()}
_STRETCHED: Final = frozenset(name for name, ratio in _RATIO_OF.items() if ratio != 1.0)
"""The sensor types whose views have a ratio other than 1 (unknown types count as 1)."""


def depth_noise_ratios(sensor_types: Sequence[str]) -> FloatArray | None:
    """(N,) each view's ``depth_noise_ratio`` from its sensor type's prior, or None when every
    view's is 1 (nothing to do; unknown types count as Kinect v2: 1)."""
    if _STRETCHED.isdisjoint(sensor_types):  # the usual rig: a set test, not a loop (5 µs)
        return None
    return np.array([_RATIO_OF.get(t, 1.0) for t in sensor_types], dtype=np.float64)


def ray_weighted_mean(
    joints: FloatArray,
    weights: FloatArray,
    sensors: FloatArray,
    ratios: FloatArray,
    fused: FloatArray | None = None,
) -> FloatArray:
    """Each person's joints fused with each view's noise stretched along its sensor's ray.

    Args:
        joints: (P, S, J, 3) views; NaN where a view has no position.
        weights: (P, S, J) non-negative (inverse variance across the ray).
        sensors: (P, S, 3) where each view's sensor stands; NaN when unknown (that view then
            counts as the same in every direction).
        ratios: (P, S) each view's noise along the ray over across it, >= 1 (1: isotropic).
        fused: (P, J, 3) the plain weighted mean already computed, or None; persons without a
            ratio other than 1 keep its values unchanged (the same bits).

    Returns:
        (P, J, 3) float64; NaN where no view has a position with a positive weight.

    Raises:
        ValueError: on a ratio below 1 or not finite.
    """
    if not (np.isfinite(ratios).all() and (ratios >= 1.0).all()):
        raise ValueError(f"depth noise ratios must be finite and >= 1, got {ratios}")
    out = np.full(joints.shape[0:1] + joints.shape[2:], np.nan) if fused is None else fused.copy()
    ray_loop(plain(joints), plain(weights), plain(sensors), plain(ratios), fused is None, out)
    return out


@jit
def ray_loop(
    joints: FloatArray,
    weights: FloatArray,
    sensors: FloatArray,
    ratios: FloatArray,
    every: bool,
    out: FloatArray,
) -> None:
    """Fill ``out`` (P, J, 3) with :func:`ray_weighted_mean` for the persons with a ratio other
    than 1 (``every``: for every person): per joint the symmetric information matrix
    ``Σ w·(I + (1/ratio² − 1)·d·dᵀ)`` and its right side, solved by Cramer's rule (NaN where
    no view counts)."""
    for p in range(joints.shape[0]):
        stretched = every
        for s in range(joints.shape[1]):
            stretched = stretched or ratios[p, s] != 1.0
        if not stretched:
            continue
        for j in range(joints.shape[2]):
            a00 = a01 = a02 = a11 = a12 = a22 = b0 = b1 = b2 = 0.0
            for s in range(joints.shape[1]):
                w = weights[p, s, j]
                x0, x1, x2 = joints[p, s, j, 0], joints[p, s, j, 1], joints[p, s, j, 2]
                if not (w > 0.0 and math.isfinite(x0 + x1 + x2)):
                    continue
                d0, d1, d2 = x0 - sensors[p, s, 0], x1 - sensors[p, s, 1], x2 - sensors[p, s, 2]
                length = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                shrink = 0.0  # no ray known: the same in every direction
                if length > 0.0 and math.isfinite(length):
                    shrink = w * (1.0 / (ratios[p, s] * ratios[p, s]) - 1.0)
                    d0, d1, d2 = d0 / length, d1 / length, d2 / length
                else:
                    d0 = d1 = d2 = 0.0
                along = shrink * (d0 * x0 + d1 * x1 + d2 * x2)
                a00 += w + shrink * d0 * d0
                a11 += w + shrink * d1 * d1
                a22 += w + shrink * d2 * d2
                a01 += shrink * d0 * d1
                a02 += shrink * d0 * d2
                a12 += shrink * d1 * d2
                b0 += w * x0 + along * d0
                b1 += w * x1 + along * d1
                b2 += w * x2 + along * d2
            c00 = a11 * a22 - a12 * a12  # the cofactors of the symmetric matrix
            c01 = a02 * a12 - a01 * a22
            c02 = a01 * a12 - a02 * a11
            det = a00 * c00 + a01 * c01 + a02 * c02
            if not det > 0.0:
                out[p, j, 0] = out[p, j, 1] = out[p, j, 2] = math.nan
                continue
            c11 = a00 * a22 - a02 * a02
            c12 = a01 * a02 - a00 * a12
            c22 = a00 * a11 - a01 * a01
            out[p, j, 0] = (c00 * b0 + c01 * b1 + c02 * b2) / det
            out[p, j, 1] = (c01 * b0 + c11 * b1 + c12 * b2) / det
            out[p, j, 2] = (c02 * b0 + c12 * b1 + c22 * b2) / det


def warm_up() -> None:
    """Compile (or load from numba's cache) this module's loops now."""
    facing_cosines(np.array([1.0, 0.0, 0.0]), np.zeros(3), np.ones((2, 3)))
    ray_weighted_mean(np.ones((1, 2, 25, 3)), np.ones((1, 2, 25)), np.zeros((1, 2, 3)),
                      np.full((1, 2), 2.0))  # fmt: skip
