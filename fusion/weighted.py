"""Fusion math: pure functions on arrays, no I/O.

Report A (``shared/papers.md``): sensor k sees joint n at J_kn with confidence C_kn; the fused
joint is the confidence-weighted mean ``J_n = Σ_k C_kn·J_kn / Σ_k C_kn`` with C from the tracking
state (NotTracked 0, Inferred 0.3, Tracked 0.7) times the body-based terms of
:mod:`fusion.confidence` (bone length, range of motion, facing, distance). After fusion,
:func:`robust_reweight` can discount views far from the consensus and
:func:`enforce_bone_lengths` gives the skeleton the person's reference bone lengths.

Shapes: S views of one person, J = 25 joints. Positions in metres, world frame.
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.fusion.confidence import CHAIN_LEVELS
from skelfuse.protocol.skeleton import BONES, JOINT_COUNT, JointId

FloatArray = npt.NDArray[np.float64]

TRUNK_JOINTS: Final = np.array(
    [JointId.SPINE_BASE, JointId.SPINE_MID, JointId.SPINE_SHOULDER, JointId.NECK, JointId.HEAD]
)
"""Joints on the body's midline: the same whatever a sensor thinks is left or right."""
_BONE_PARENT: Final = np.array([parent for parent, _ in BONES])
_BONE_CHILD: Final = np.array([child for _, child in BONES])


def state_weights(states: npt.ArrayLike, table: tuple[float, float, float]) -> FloatArray:
    """Per-joint weights from tracking states.

    Args:
        states: (S, J) uint8 TrackingState values.
        table: weight of NotTracked, Inferred, Tracked.

    Returns:
        (S, J) float64 weights.
    """
    return np.asarray(table, dtype=np.float64)[np.asarray(states, dtype=np.intp)]


def fuse_views(joints: npt.ArrayLike, weights: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Confidence-weighted mean of S views of one person (report A, eq. 2).

    Args:
        joints: (S, J, 3) positions, metres, world frame; NaN where a view has no position.
        weights: (S, J) non-negative weights; a NaN position contributes nothing whatever its
            weight.

    Returns:
        fused: (J, 3) float64; NaN where no view has a positive weight.
        confidence: (J,) float64 in [0, 1]: ``1 − Π_k (1 − w_k)`` with weights clipped to
            [0, 1], the chance that at least one view is right if each is right with
            probability w_k. 0 exactly where ``fused`` is NaN.
    """
    views = np.asarray(joints, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if views.ndim != 3 or views.shape[2] != 3 or w.shape != views.shape[:2]:
        raise ValueError(
            f"expected joints (S, J, 3) and weights (S, J), got {views.shape} and {w.shape}"
        )
    fused, confidence = fuse_views_batch(views[None], w[None])
    return fused[0], confidence[0]


def fuse_views_batch(joints: FloatArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """:func:`fuse_views` of P persons at once.

    Args:
        joints: (P, S, J, 3); a person with fewer views is padded with NaN views.
        weights: (P, S, J); 0 on padding.

    Returns:
        fused (P, J, 3) and confidence (P, J), each person's exactly as :func:`fuse_views`
        (padding adds zeros after the real views, which changes no sum or product).
    """
    usable = np.isfinite(joints).all(axis=3) & (weights > 0)
    w = np.where(usable, weights, 0.0)
    total = w.sum(axis=1)
    safe_views = np.where(usable[..., None], joints, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        fused = (w[..., None] * safe_views).sum(axis=1) / total[..., None]
    empty = total <= 0
    fused[empty] = np.nan
    confidence = 1.0 - np.prod(1.0 - np.clip(w, 0.0, 1.0), axis=1)
    confidence[empty] = 0.0
    return fused, confidence


def trunk_distance(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Mean distance between the midline joints two skeletons both have (metres).

    Used to decide whether two views (or a view and a track) are the same person. Midline
    joints make it immune to a sensor swapping left and right. ``inf`` with nothing in common.

    Args:
        a, b: (25, 3) joints, metres, same frame; NaN where unknown.
    """
    pa = np.asarray(a, dtype=np.float64)[TRUNK_JOINTS]
    pb = np.asarray(b, dtype=np.float64)[TRUNK_JOINTS]
    both = np.isfinite(pa).all(axis=1) & np.isfinite(pb).all(axis=1)
    if both.sum() < 2:
        return float("inf")
    return float(np.linalg.norm(pa[both] - pb[both], axis=1).mean())


def mpjpe(estimate: npt.ArrayLike, truth: npt.ArrayLike) -> tuple[float, int]:
    """Mean per-joint position error over the joints the estimate has (metres), and how many.

    Args:
        estimate, truth: (..., 25, 3) positions in the same frame; NaN in ``estimate`` means the
            joint was not reported and is left out (the count tells how many were scored).
    """
    est = np.asarray(estimate, dtype=np.float64).reshape(-1, JOINT_COUNT, 3)
    ref = np.asarray(truth, dtype=np.float64).reshape(-1, JOINT_COUNT, 3)
    err = np.linalg.norm(est - ref, axis=-1)
    present = np.isfinite(err)
    if not present.any():
        return float("nan"), 0
    return float(err[present].mean()), int(present.sum())


def robust_reweight(
    joints: npt.ArrayLike, weights: npt.ArrayLike, fused: npt.ArrayLike, scale_m: float
) -> FloatArray:
    """One Cauchy re-weighting pass: views far from the weighted mean count less.

    Args:
        joints: (S, J, 3) views, metres; weights: (S, J); fused: (J, 3) their weighted mean.
        scale_m: distance at which a view's weight is halved.

    Returns:
        (S, J) weights × ``1 / (1 + (d / scale)²)``, d the view's distance to ``fused``.
    """
    views = np.asarray(joints, dtype=np.float64)
    d = np.linalg.norm(views - np.asarray(fused, dtype=np.float64)[None], axis=-1)
    factor = np.where(np.isfinite(d), 1.0 / (1.0 + (d / scale_m) ** 2), 1.0)
    result: FloatArray = np.asarray(weights, dtype=np.float64) * factor
    return result


def contributors(weights: npt.ArrayLike, min_share: float = 0.05) -> npt.NDArray[np.int64]:
    """Which views contributed to each joint, as a bitmask (bit k: view k).

    Args:
        weights: (S, J) final fusion weights (0 where a view has no position).
        min_share: a view counts when it carries at least this share of the joint's weight.

    Returns:
        (J,) int64 bitmasks; 0 where no view has the joint.
    """
    w = np.asarray(weights, dtype=np.float64)
    total = w.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(total > 0, w / total, 0.0)
    bits = (share >= min_share) & (w > 0)
    mask: npt.NDArray[np.int64] = (bits.astype(np.int64) << np.arange(w.shape[0])[:, None]).sum(
        axis=0
    )
    return mask


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
    offsets = original[..., _BONE_CHILD, :] - original[..., _BONE_PARENT, :]  # (..., 24, 3)
    # np.vecdot is the dot product np.linalg.norm uses on one vector (the same bits).
    norms = np.sqrt(np.vecdot(offsets, offsets))
    scale = np.isfinite(ref) & np.isfinite(norms) & (norms > 1e-9)
    with np.errstate(invalid="ignore", divide="ignore"):
        factors = ref / norms
    offset_of = np.empty(original.shape)
    offset_of[..., _BONE_CHILD, :] = np.where(
        scale[..., None], offsets * factors[..., None], offsets
    )
    out = original.copy()
    # Outward one depth level at a time; a joint whose parent is missing keeps its measurement.
    for children, parents in CHAIN_LEVELS:
        hung = np.isfinite(out[..., parents, :]).all(axis=-1, keepdims=True)
        out[..., children, :] = np.where(
            hung, out[..., parents, :] + offset_of[..., children, :], out[..., children, :]
        )
    return out


def _bone_groups() -> tuple[npt.NDArray[np.intp], ...]:
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
            a bone to leave alone. mobility: (..., 25) how freely each joint may move (> 0;
            e.g. 1 − confidence); None: all alike.

    Returns:
        (..., 25, 3) float64; NaN joints stay NaN.
    """
    original = np.asarray(joints, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    missing = np.asarray(~np.isfinite(original).all(axis=-1))  # (..., 25)
    out = np.where(missing[..., None], 0.0, original)  # NaN-free while iterating
    move = np.ones(out.shape[:-1]) if mobility is None else np.asarray(mobility, np.float64)
    move = np.maximum(move, 1e-6)
    # Per group, fixed over the passes: its bones' ends, targets and the ends' shares (0 for a
    # bone with an unknown target or a missing end: it moves nothing).
    plan = []
    for group in BONE_GROUPS:
        parents, children = _BONE_PARENT[group], _BONE_CHILD[group]
        target = ref[..., group]
        usable = np.isfinite(target) & ~missing[..., parents] & ~missing[..., children]
        m_parent, m_child = move[..., parents], move[..., children]
        share = np.where(usable, m_parent / (m_parent + m_child), 0.0)[..., None]
        rest = np.where(usable, 1.0, 0.0)[..., None] - share
        plan.append((parents, children, np.where(usable, target, 0.0), share, rest))
    for _ in range(iterations):
        for parents, children, target, share, rest in plan:
            offsets = out[..., children, :] - out[..., parents, :]
            norms = np.maximum(np.sqrt(np.vecdot(offsets, offsets)), 1e-12)
            delta = offsets * ((norms - target) / norms)[..., None]
            out[..., parents, :] += share * delta
            out[..., children, :] -= rest * delta
    out[missing] = np.nan
    return enforce_bone_lengths(out, ref)
