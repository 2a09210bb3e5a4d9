"""The bone-length fit: a skeleton given its person's reference lengths.

Two fits: :func:`enforce_bone_lengths` rescales bone after bone outward from SpineBase;
:func:`project_bone_lengths` moves both ends of every bone (position-based distance constraints,
one compiled loop per skeleton) and ends with that outward pass.

Shapes: 25 joints, 24 bones in :data:`skelfuse.protocol.skeleton.BONES` order; metres.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.anatomy import CHAIN_LEVELS, CHAIN_ORDER
from skelfuse.jit import jit, jit_inline, plain
from skelfuse.protocol.skeleton import BONES, PARENTS

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BONE_COUNT: Final = len(BONES)
BONE_PARENT: Final = np.array([parent for parent, _ in BONES])
BONE_CHILD: Final = np.array([child for _, child in BONES])


def enforce_bone_lengths(joints: npt.ArrayLike, reference: npt.ArrayLike) -> FloatArray:
    """Give a skeleton the reference bone lengths, keeping every bone's direction.

    Walks outward from SpineBase: each child is put at ``parent' + unit(child − parent)·l_ref``
    where ``parent'`` is the already-corrected parent. A bone whose reference is unknown (NaN)
    keeps its measured offset; NaN joints stay NaN.

    Args:
        joints: (25, 3) metres; reference: (24,) metres in :data:`BONES` order. Or several
            skeletons at once: (..., 25, 3) and (..., 24).

    Returns:
        (25, 3) float64 (or (..., 25, 3)).
    """
    original = np.asarray(joints, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    offsets = np.take(original, BONE_CHILD, axis=-2) - np.take(original, BONE_PARENT, axis=-2)
    # np.vecdot is the dot product np.linalg.norm uses on one vector (the same bits).
    norms = np.sqrt(np.vecdot(offsets, offsets))  # (..., 24)
    scale = np.isfinite(ref) & np.isfinite(norms) & (norms > 1e-9)
    factors = np.divide(ref, norms, out=np.ones_like(norms), where=scale)
    # SpineBase, then each bone's offset from its parent to its child, in BONES order.
    sources = np.concatenate(
        [
            original[..., _ROOT : _ROOT + 1, :],
            np.where(scale[..., None], offsets * factors[..., None], offsets),
        ],
        axis=-2,
    )
    # Every joint at once: its root-to-joint path's running sum, SpineBase then each bone's
    # offset in turn, which is the sum the walk below makes, in the same order (the same bits).
    # It holds wherever every parent is known: so wherever the result is all finite.
    summed = np.cumsum(np.take(sources, _PATH_SOURCES, axis=-2), axis=-2)
    result: FloatArray = np.take(
        summed.reshape(*summed.shape[:-3], _PATHS.size, 3), _PATH_INDEX, axis=-2
    )
    if np.isfinite(result).all():
        return result
    out = original.copy()
    # Outward one depth level at a time; a joint whose parent is missing keeps its measurement.
    for children, parents in CHAIN_LEVELS:
        hung = np.isfinite(out[..., parents, :]).all(axis=-1, keepdims=True)
        out[..., children, :] = np.where(
            hung,
            out[..., parents, :] + sources[..., _SOURCE_OF[children], :],
            out[..., children, :],
        )
    return out


def _chain_paths() -> tuple[int, IntArray, IntArray, IntArray]:
    """SpineBase, every root-to-leaf path of joints (padded with the leaf), and per joint the
    path holding it and its depth on that path."""
    parent_of = {int(child): int(parent) for parent, child in BONES}
    root = next(iter({*parent_of.values()} - {*parent_of}))
    leaves = sorted({*parent_of} - {*parent_of.values()})
    paths = []
    for leaf in leaves:
        path = [leaf]
        while path[-1] != root:
            path.append(parent_of[path[-1]])
        paths.append(path[::-1])
    width = max(len(path) for path in paths)
    padded = np.array([path + [path[-1]] * (width - len(path)) for path in paths], dtype=np.intp)
    path_of = np.zeros(len(parent_of) + 1, dtype=np.intp)
    depth_of = np.zeros(len(parent_of) + 1, dtype=np.intp)
    for k, path in enumerate(paths):
        for depth, joint in enumerate(path):
            path_of[joint], depth_of[joint] = k, depth
    return root, padded, path_of, depth_of


_ROOT, _PATHS, _PATH_OF, _DEPTH_OF = _chain_paths()
_SOURCE_OF: Final = np.zeros(len(_PATH_OF), dtype=np.intp)
_SOURCE_OF[BONE_CHILD] = 1 + np.arange(BONE_COUNT)
"""Per joint, its row in ``enforce_bone_lengths``' sources: 0 SpineBase, 1 + the bone ending
there."""
_PATH_SOURCES: Final = _SOURCE_OF[_PATHS]
_PATH_INDEX: Final = _PATH_OF * _PATHS.shape[1] + _DEPTH_OF
"""Per joint, where its running sum lies in the flattened (paths × depth) sums."""


def _bone_groups() -> tuple[IntArray, ...]:
    """Bones split into groups that share no joint (a greedy edge colouring of the tree), so a
    group's corrections can be applied at once without two bones writing the same joint."""
    groups: list[list[int]] = []
    used: list[set[int]] = []
    for b, (parent, child) in enumerate(BONES):
        for group, joints in zip(groups, used, strict=True):
            if parent not in joints and child not in joints:
                group.append(b)
                joints.update((parent, child))
                break
        else:
            groups.append([b])
            used.append({parent, child})
    return tuple(np.array(g, dtype=np.intp) for g in groups)


BONE_GROUPS: Final = _bone_groups()
_BONE_TO_JOINT: Final = _SOURCE_OF - 1
_BONE_TO_JOINT[_ROOT] = -1
BONE_TABLES: Final = (
    np.concatenate(BONE_GROUPS),
    BONE_PARENT,
    BONE_CHILD,
    np.array(CHAIN_ORDER, dtype=np.intp),
    np.array([max(parent, 0) for parent in PARENTS], dtype=np.intp),
    _BONE_TO_JOINT,
)
"""The index tables of :func:`project_loop`: the bones in group order, each bone's parent and
child, the joints parents first, each joint's parent (SpineBase: itself, unused) and the bone
ending at each joint (−1: SpineBase)."""


def warm_up() -> None:
    """Compile (or load from numba's cache) the projection's loop now, off any latency-bound
    path."""
    project_bone_lengths(np.zeros((2, 25, 3)), np.ones((2, 24)), np.ones((2, 25)), 1)


def project_bone_lengths(
    joints: npt.ArrayLike,
    reference: npt.ArrayLike,
    mobility: npt.ArrayLike | None = None,
    iterations: int = 3,
) -> FloatArray:
    """Give a skeleton the reference bone lengths while moving its joints as little as possible.

    Position-based distance constraints: each pass shortens or lengthens every bone to its
    reference by moving both ends along the bone, the parent by the share ``m_p / (m_p + m_c)``
    of the mobilities; ``iterations`` passes (Gauss–Seidel over :data:`BONE_GROUPS`) then one
    outward :func:`enforce_bone_lengths` pass make the lengths exact. Unlike that pass alone,
    which keeps SpineBase fixed and pushes a whole subtree along with every correction, the
    correction is spread over both ends, so errors do not pile up towards the hands and feet.

    Args:
        joints: (..., 25, 3) metres. reference: (..., 24) metres in :data:`BONES` order, NaN for
            a bone to leave alone. mobility: (..., 25) how freely each joint may move (> 0,
            floored at 1e-6; e.g. 1 − confidence); None: all alike. Leading axes broadcast.

    Returns:
        (..., 25, 3) float64; NaN joints stay NaN.
    """
    original = np.asarray(joints, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if ref.shape[:-1] != original.shape[:-2]:  # one reference for many skeletons, or the reverse
        lead = np.broadcast_shapes(original.shape[:-2], ref.shape[:-1])
        original = np.broadcast_to(original, (*lead, *original.shape[-2:]))
        ref = np.broadcast_to(ref, (*lead, ref.shape[-1]))
    shape = original.shape
    if mobility is None:  # all alike: ones, which the floor leaves as they are
        move = np.ones(shape[:-1])
    else:
        move = np.maximum(np.asarray(mobility, np.float64), 1e-6)
        if move.shape != shape[:-1]:
            move = np.broadcast_to(move, shape[:-1])
    flat = plain(original.reshape(-1, 25, 3))
    out = np.empty_like(flat)
    grouped, parents, children, order, parent_of, bone_to = (plain(t, np.intp) for t in BONE_TABLES)
    project_loop(
        flat,
        plain(ref.reshape(-1, ref.shape[-1])),
        plain(move.reshape(-1, 25)),
        int(iterations),
        grouped,
        parents,
        children,
        order,
        parent_of,
        bone_to,
        out,
    )
    result: FloatArray = out.reshape(shape)
    return result


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
    :data:`BONE_GROUPS` order (the bones of one group share no joint, so moving them one after
    the other is moving them at once); parent_of_bone, child_of_bone: (24,); chain_order:
    joints, parents before children (SpineBase first); parent_of_joint: (25,); bone_to_joint:
    (25,) the bone ending at each joint (−1 for SpineBase).
    """
    bones = grouped.shape[0]
    rows = np.empty((25, 3))  # the skeleton being fitted, unknown joints at 0 meanwhile
    missing = np.empty(25, dtype=np.bool_)
    share = np.empty(bones)
    rest = np.empty(bones)
    target = np.empty(bones)
    source = np.empty((25, 3))
    for p in range(joints.shape[0]):
        _start(joints[p], rows, missing)
        _plan(reference[p], move[p], grouped, parent_of_bone, child_of_bone, missing, share,
              rest, target)  # fmt: skip
        for _ in range(iterations):
            _project_pass(rows, grouped, parent_of_bone, child_of_bone, share, rest, target)
        for j in range(25):
            if missing[j]:
                rows[j, 0] = rows[j, 1] = rows[j, 2] = math.nan
        _outward(rows, reference[p], parent_of_bone, chain_order, parent_of_joint,
                 bone_to_joint, source, out[p])  # fmt: skip


@jit_inline
def _maximum(x: float, floor: float) -> float:
    """``np.maximum(x, floor)`` (NaN stays NaN)."""
    if x >= floor or x != x:
        return x
    return floor


@jit_inline
def _start(joints: FloatArray, rows: FloatArray, missing: npt.NDArray[np.bool_]) -> None:
    """``rows`` (25, 3): ``joints`` with every joint that has a non-finite coordinate at 0,
    which ``missing`` (25,) marks."""
    for j in range(25):
        known = True
        for c in range(3):
            if not math.isfinite(joints[j, c]):
                known = False
        missing[j] = not known
        for c in range(3):
            rows[j, c] = joints[j, c] if known else 0.0


@jit_inline
def _plan(
    reference: FloatArray,
    move: FloatArray,
    grouped: IntArray,
    parent_of_bone: IntArray,
    child_of_bone: IntArray,
    missing: npt.NDArray[np.bool_],
    share: FloatArray,
    rest: FloatArray,
    target: FloatArray,
) -> None:
    """Per bone in group order, fixed over the passes: the parent's ``share`` and the child's
    ``rest`` of each correction and the ``target`` length (all 0 for a bone with an unknown
    reference or a missing end: it moves nothing)."""
    for k in range(grouped.shape[0]):
        b = grouped[k]
        parent, child = parent_of_bone[b], child_of_bone[b]
        length = reference[b]
        usable = math.isfinite(length) and not missing[parent] and not missing[child]
        m_parent, m_child = move[parent], move[child]
        share[k] = m_parent / (m_parent + m_child) if usable else 0.0
        rest[k] = (1.0 if usable else 0.0) - share[k]
        target[k] = length if usable else 0.0


@jit_inline
def _project_pass(
    rows: FloatArray,
    grouped: IntArray,
    parent_of_bone: IntArray,
    child_of_bone: IntArray,
    share: FloatArray,
    rest: FloatArray,
    target: FloatArray,
) -> None:
    """One Gauss–Seidel pass: each bone in turn to its target, both ends moved along it."""
    for k in range(grouped.shape[0]):
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


@jit_inline
def _outward(
    rows: FloatArray,
    reference: FloatArray,
    parent_of_bone: IntArray,
    chain_order: IntArray,
    parent_of_joint: IntArray,
    bone_to_joint: IntArray,
    source: FloatArray,
    out: FloatArray,
) -> None:
    """:func:`enforce_bone_lengths` of ``rows`` (25, 3) into ``out`` (25, 3): each bone's
    offset rescaled to its reference (``source``, scratch), added to its already placed parent
    root first; a joint whose parent is unknown keeps its row."""
    for j in range(25):
        b = bone_to_joint[j]
        if b < 0:
            continue
        parent = parent_of_bone[b]
        o0 = rows[j, 0] - rows[parent, 0]
        o1 = rows[j, 1] - rows[parent, 1]
        o2 = rows[j, 2] - rows[parent, 2]
        norm = math.sqrt((o0 * o0 + o1 * o1) + o2 * o2)
        length = reference[b]
        if math.isfinite(length) and math.isfinite(norm) and norm > 1e-9:
            factor = length / norm
            o0, o1, o2 = o0 * factor, o1 * factor, o2 * factor
        source[j, 0], source[j, 1], source[j, 2] = o0, o1, o2
    for c in range(3):
        out[chain_order[0], c] = rows[chain_order[0], c]
    for i in range(1, 25):
        j = chain_order[i]
        parent = parent_of_joint[j]
        hung = True
        for c in range(3):
            if not math.isfinite(out[parent, c]):
                hung = False
        for c in range(3):
            out[j, c] = out[parent, c] + source[j, c] if hung else rows[j, c]
