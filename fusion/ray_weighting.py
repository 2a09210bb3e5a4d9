"""Fusion that knows a view's noise is larger along its sensor's viewing ray than across it.

A camera that places a body from its apparent size (the ``rgb`` sensor type,
agent/sources/mono.py) knows well where a joint is across the image and poorly how far it is:
its variance along the ray from the sensor to the joint is ``ratio²`` times that across it
(``SensorPrior.depth_noise_ratio``, fusion/priors.py). Treating each view as a Gaussian with
covariance ``σ²·(I + (ratio² − 1)·d·dᵀ)`` (d the unit ray) and its weight w as 1/σ², the fused
joint is the information-weighted mean::

    x = (Σ w·A)⁻¹ · Σ w·A·x_view,   A = I + (1/ratio² − 1)·d·dᵀ  (the inverse covariance shape)

With every ratio 1 this is :func:`fusion.weighted.weighted_mean`; with one view it is that view.
A second view from another direction then fixes the camera's depth while the camera keeps its
say across the image. Only persons with at least one such view are recomputed, so fusion of
Kinect-only rigs keeps its exact bits (the golden replay digests).

Shapes as in :mod:`fusion.weighted`: P persons, S views each (padded with NaN views of weight
0), J joints; metres, world frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.points import finite_points
from skelfuse.fusion.priors import PRIORS

FloatArray = npt.NDArray[np.float64]

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
    persons = np.flatnonzero((ratios != 1.0).any(axis=1)) if fused is not None else None
    if persons is not None and len(persons) == 0:
        return out
    pick = slice(None) if persons is None else persons
    x, w, s, r = joints[pick], weights[pick], sensors[pick], ratios[pick]
    usable = finite_points(x) & (w > 0)
    w = np.where(usable, w, 0.0)
    x = np.where(usable[..., None], x, 0.0)
    ray = x - s[:, :, None, :]
    length = np.linalg.norm(ray, axis=-1, keepdims=True)
    known = np.isfinite(length) & (length > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(known, ray / length, 0.0)  # (P, S, J, 3) unit rays, 0 where unknown
    shrink = (1.0 / r**2 - 1.0)[:, :, None] * w  # (P, S, J): w·(1/ratio² − 1), <= 0
    total = w.sum(axis=1)  # (P, J)
    info = total[..., None, None] * np.eye(3) + np.einsum("psj,psja,psjb->pjab", shrink, d, d)
    along = (d * x).sum(axis=-1)  # (P, S, J) each view's position along its own ray
    rhs = (w[..., None] * x).sum(axis=1) + (shrink[..., None] * d * along[..., None]).sum(axis=1)
    seen = total > 0
    result = np.full(rhs.shape, np.nan)
    result[seen] = np.linalg.solve(info[seen], rhs[seen][..., None])[..., 0]
    out[pick] = result
    return out
