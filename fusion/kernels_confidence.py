"""The per-joint confidence as loops, for a compiled kernel.

:func:`body_loop` is :func:`skelfuse.fusion.confidence.body_weights` for views whose sensors
all use the settings' state table (no per-sensor prior changes anything), and
:func:`confidence_loop` is :func:`skelfuse.fusion.confidence.joint_confidence` with
:func:`skelfuse.fusion.weighted.carriers`, written as scalar code: :mod:`skelfuse.fusion.kernels`
compiles them with numba. The same IEEE operations in the same order, so the same bits: a bone
length is ``sqrt((dx² + dy²) + dz²)`` as ``np.linalg.norm`` over three components, products and
sums over a person's views start from 1 and 0 and take view after view, factors multiply
outward along the chain parent first, as :func:`~skelfuse.fusion.confidence.propagate`, and
``exp`` is the C library's, as numpy's loop calls it (the tests compare both paths).

Imported only by :mod:`skelfuse.fusion.kernels` when the kernels run; without numba
:func:`~skelfuse.fusion.kernels_jit.jit` leaves the functions plain Python (slow, same results).
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
def body_loop(
    joints: FloatArray,
    states: npt.NDArray[np.uint8],
    table: FloatArray,
    references: FloatArray,
    rom: FloatArray,
    flags: BoolArray,
    scale_m: float,
    bones: tuple[IntArray, IntArray],
    chain: tuple[IntArray, IntArray],
    out: FloatArray,
) -> None:
    """Fill ``out`` (N, 25) with each joint's weight from its view alone (``body_weights``).

    joints: (N, 25, 3); states: (N, 25) tracking states, indices into ``table`` (3,);
    references: (N, 24) reference bone lengths (read when ``flags[0]``); rom: (N, 25)
    range-of-motion factors (read when ``flags[1]``); scale_m: the bone-length scale;
    bones: each bone's parent and child joint; chain: the joints below SpineBase parent first,
    and their parents.
    """
    parents, children = bones
    order, parent_of = chain
    local = np.empty(joints.shape[1])
    for v in range(joints.shape[0]):
        for j in range(len(local)):
            local[j] = 1.0
        if flags[0]:  # bone length: exp(−|l − l_ref| / scale) on each bone's child
            for b in range(len(parents)):
                a, c = joints[v, children[b]], joints[v, parents[b]]
                d0, d1, d2 = a[0] - c[0], a[1] - c[1], a[2] - c[2]
                diff = abs(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - references[v, b])
                local[children[b]] = math.exp(-diff / scale_m) if math.isfinite(diff) else 1.0
        if flags[1]:
            for j in range(len(local)):
                local[j] *= rom[v, j]
        for k in range(len(order)):  # outward from SpineBase: each parent already final
            local[order[k]] *= local[parent_of[k]]
        for j in range(len(local)):
            out[v, j] = table[states[v, j]] * local[j]


@jit
def confidence_loop(
    joints: FloatArray,
    weights: FloatArray,
    min_share: float,
    confidence: FloatArray,
    carried: BoolArray,
) -> None:
    """Fill ``confidence`` (P, J) and ``carried`` (P, S, J) from each person's views as fused.

    joints: (P, S, J, 3) NaN where a view has no position; weights: (P, S, J) the final
    weights. ``1 − Π (1 − clip(w, 0, 1))`` over the views with a position and a positive weight
    (0 where none), and which views hold at least ``min_share`` of a joint's weight.
    """
    size, views, count = weights.shape
    for p in range(size):
        for j in range(count):
            product = 1.0
            usable_total = 0.0
            total = 0.0
            for s in range(views):
                point = joints[p, s, j]
                finite = math.isfinite(point[0]) and math.isfinite(point[1])
                finite = finite and math.isfinite(point[2])
                weight = weights[p, s, j]
                used = weight if finite and weight > 0 else 0.0
                clipped = 0.0 if used < 0.0 else (1.0 if used > 1.0 else used)
                product *= 1.0 - clipped
                usable_total += used
                total += weight if finite else 0.0
            confidence[p, j] = 0.0 if usable_total <= 0 else 1.0 - product
            for s in range(views):
                point = joints[p, s, j]
                finite = math.isfinite(point[0]) and math.isfinite(point[1])
                finite = finite and math.isfinite(point[2])
                final = weights[p, s, j] if finite else 0.0
                share = final / total if total > 0 else 0.0
                carried[p, s, j] = share >= min_share and final > 0
