"""The bone-length projection as one loop per skeleton, for a compiled kernel.

:func:`project_loop` is :func:`skelfuse.fusion.bones.project_bone_lengths` (then its
:func:`~skelfuse.fusion.bones.enforce_bone_lengths` pass) written as scalar code:
:mod:`skelfuse.fusion.kernels` compiles it with numba. The same IEEE operations in the same
order as the numpy version, so the same bits: the bones of one group share no joint, so moving
them one after the other is moving them at once; a dot product is (a₀a₀ + a₁a₁) + a₂a₂, as
``np.vecdot`` sums three products; ``np.maximum`` passes NaN through; the outward pass adds each
bone's offset to its already placed parent, root first, as the numpy version's running sums.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.kernels_jit import jit

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


@jit
def _maximum(x: float, floor: float) -> float:
    """``np.maximum(x, floor)`` (NaN stays NaN)."""
    if x >= floor or x != x:
        return x
    return floor


@jit
def project_loop(
    joints: FloatArray,
    reference: FloatArray,
    move: FloatArray,
    iterations: int,
    grouped: IntArray,
    parent_of_bone: IntArray,
    child_of_bone: IntArray,
    chain_order: IntArray,
    parent_of_joint: IntArray,
    bone_to_joint: IntArray,
    out: FloatArray,
) -> None:
    """Fill ``out`` (P, 25, 3) with ``joints`` (P, 25, 3) given ``reference`` (P, 24) lengths.

    move: (P, 25) mobilities (already floored at 1e-6); grouped: the bones in
    :data:`~skelfuse.fusion.bones.BONE_GROUPS` order; parent_of_bone, child_of_bone: (24,);
    chain_order: joints, parents before children (SpineBase first); parent_of_joint: (25,);
    bone_to_joint: (25,) the bone ending at each joint (−1 for SpineBase).
    """
    bones = grouped.shape[0]
    rows = np.empty((25, 3))
    missing = np.empty(25, dtype=np.bool_)
    share = np.empty(bones)
    rest = np.empty(bones)
    target = np.empty(bones)
    source = np.empty((25, 3))
    for p in range(joints.shape[0]):
        for j in range(25):
            known = True
            for c in range(3):
                if not math.isfinite(joints[p, j, c]):
                    known = False
            missing[j] = not known
            for c in range(3):
                rows[j, c] = joints[p, j, c] if known else 0.0
        for k in range(bones):
            b = grouped[k]
            parent, child = parent_of_bone[b], child_of_bone[b]
            length = reference[p, b]
            usable = math.isfinite(length) and not missing[parent] and not missing[child]
            m_parent, m_child = move[p, parent], move[p, child]
            share[k] = m_parent / (m_parent + m_child) if usable else 0.0
            rest[k] = (1.0 if usable else 0.0) - share[k]
            target[k] = length if usable else 0.0
        for _ in range(iterations):
            for k in range(bones):
                b = grouped[k]
                parent, child = parent_of_bone[b], child_of_bone[b]
                o0 = rows[child, 0] - rows[parent, 0]
                o1 = rows[child, 1] - rows[parent, 1]
                o2 = rows[child, 2] - rows[parent, 2]
                norm = _maximum(math.sqrt((o0 * o0 + o1 * o1) + o2 * o2), 1e-12)
                ratio = (norm - target[k]) / norm
                d0, d1, d2 = o0 * ratio, o1 * ratio, o2 * ratio
                rows[parent, 0] += share[k] * d0
                rows[parent, 1] += share[k] * d1
                rows[parent, 2] += share[k] * d2
                rows[child, 0] += -rest[k] * d0
                rows[child, 1] += -rest[k] * d1
                rows[child, 2] += -rest[k] * d2
        for j in range(25):
            if missing[j]:
                rows[j, 0] = rows[j, 1] = rows[j, 2] = math.nan
        # The outward pass (bones.enforce_bone_lengths) on the projected joints.
        for j in range(25):
            b = bone_to_joint[j]
            if b < 0:
                continue
            parent = parent_of_bone[b]
            o0 = rows[j, 0] - rows[parent, 0]
            o1 = rows[j, 1] - rows[parent, 1]
            o2 = rows[j, 2] - rows[parent, 2]
            norm = math.sqrt((o0 * o0 + o1 * o1) + o2 * o2)
            length = reference[p, b]
            if math.isfinite(length) and math.isfinite(norm) and norm > 1e-9:
                factor = length / norm
                o0, o1, o2 = o0 * factor, o1 * factor, o2 * factor
            source[j, 0], source[j, 1], source[j, 2] = o0, o1, o2
        for c in range(3):
            out[p, chain_order[0], c] = rows[chain_order[0], c]
        for i in range(1, 25):
            j = chain_order[i]
            parent = parent_of_joint[j]
            hung = True
            for c in range(3):
                if not math.isfinite(out[p, parent, c]):
                    hung = False
            for c in range(3):
                out[p, j, c] = out[p, parent, c] + source[j, c] if hung else rows[j, c]
