"""Per-joint orientations of fused skeletons, as unit quaternions, for the live feed.

The rig is the BVH export's (:mod:`skelfuse.recording.bvh_rig`): its rest pose (T-pose facing
+Z, Y up, the person's left = +X; :data:`~skelfuse.recording.bvh_rig.REST_DIRECTIONS`,
:data:`~skelfuse.recording.bvh_rig.GROUP_FRAMES`), its parent chain and its solver (Kabsch at the
joints with several children, swing plus a grandchild twist at the others, every bone aimed from
the reconstructed position of its parent). This module is that solver for one instant, run on
every person of a frame at once: ``bvh_rig.global_rotations`` on a one-frame take costs 6-14 ms
per person (a Python loop of small numpy calls), which the fusion loop cannot spend 30 times a
second; here each node is one set of numpy calls for all persons. A test holds the two to the
same rotations (``tests/unit/test_joint_orientations.py``).

What a joint's rotation means (docs/api.md, "Rotations"): the rotation of the **bone that ends
at the joint** (parent → joint), taking its rest offset onto the fused bone; the root's is the
pelvis. BVH gives each node's rotation to the bones below it, and a joint with several children
(SpineBase, SpineShoulder, the wrists) has a zero-length helper node per child so that each bone
is free; per bone, these 25 rotations are exactly the nodes' rotations that place the 25 joints,
so forward kinematics reproduces the fused positions::

    world[0] = local[0];  world[j] = world[parent[j]] · local[j]
    p[0] = root;          p[j] = p[parent[j]] + world[j] · rest_offsets[j]

With no memory between frames, a joint without fused data takes its parent's rotation (BVH's
solver keeps its previous one), and the rest offsets are this instant's own: bone lengths and the
pelvis, shoulder and hand shapes of the frame (``bvh_rig.rest_offsets`` of a one-frame take).

Quaternions are ``(x, y, z, w)`` (Hamilton, active: ``v_world = q v q*``), ``w ≥ 0``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from skelfuse.geometry.quaternion import matrix_to_quaternion
from skelfuse.protocol.skeleton import CHILDREN, JOINT_COUNT, MIRROR_PERMUTATION, PARENTS
from skelfuse.recording.bvh_rig import (
    DEFAULT_BONE_M,
    GROUP_FRAMES,
    NODE_OF,
    NODES,
    REST_DIRECTIONS,
    TWIST_PAIRS,
)

F64 = npt.NDArray[np.float64]
_EYE: Final = np.eye(3)
_EPS_M: Final = 1e-6
"""A bone shorter than this has no direction (as in the BVH rig)."""

BONE_NODE: Final[tuple[int, ...]] = tuple(
    0 if j == 0 else NODES[NODE_OF[j]].parent for j in range(JOINT_COUNT)
)
"""Per joint, the BVH node whose rotation places it: its parent's node, or the helper it hangs
from below a joint with several children; the root's own node for the root."""

_REST_DIRECTIONS: Final = np.array(
    [REST_DIRECTIONS.get(j, (0.0, 0.0, 0.0)) for j in range(JOINT_COUNT)], dtype=np.float64
)
_DEFAULT_LENGTHS: Final = np.array(
    [
        DEFAULT_BONE_M.get(j, DEFAULT_BONE_M.get(MIRROR_PERMUTATION[j], 0.0))
        for j in range(JOINT_COUNT)
    ],
    dtype=np.float64,
)  # a right-side bone takes its left counterpart's length, as in the BVH rig


@dataclass(frozen=True, slots=True)
class Orientations:
    """Orientations of P persons' joints at one instant.

    world: (P, 25, 4) quaternions ``(x, y, z, w)``, each joint's bone in the world frame.
    local: (P, 25, 4) the same relative to the parent joint's (the root's is its world one).
    rest_offsets: (P, 25, 3) metres: each joint's offset from its parent in the rest pose
        (zeros for the root).
    """

    world: F64
    local: F64
    rest_offsets: F64


def orientations(joints: npt.ArrayLike) -> Orientations:
    """Joint orientations of each person (see the module docstring for what they mean).

    Args:
        joints: (P, 25, 3) or (25, 3) fused positions, metres, world frame, NaN where unknown
            (any float dtype).

    Returns:
        Orientations with P = 1 for a (25, 3) input.

    Raises:
        ValueError: ``joints`` is not (P, 25, 3) or (25, 3).
    """
    array = np.asarray(joints, dtype=np.float64)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or array.shape[1:] != (JOINT_COUNT, 3):
        raise ValueError(f"joints must be (P, {JOINT_COUNT}, 3) or ({JOINT_COUNT}, 3)")
    with np.errstate(invalid="ignore", divide="ignore"):  # NaN joints flow through masks
        offsets = rest_offsets(array)
        nodes = node_rotations(array, offsets)
    world = nodes[:, list(BONE_NODE)]
    parent_world = world[:, [max(p, 0) for p in PARENTS]]
    local = np.einsum("pjki,pjkl->pjil", parent_world, world)  # parentᵀ · own
    local[:, 0] = world[:, 0]
    quaternions = matrix_to_quaternion(np.stack([world, local]))  # one call for both
    return Orientations(quaternions[0], quaternions[1], offsets)


def rest_offsets(joints: F64) -> F64:
    """The BVH rig's rest offsets (P, 25, 3), metres, each person's from its own frame.

    ``bvh_rig.rest_offsets`` of a one-frame take, for P persons at once: single bones this
    frame's length along the rest direction (the default length where unknown); the children of
    SpineBase, SpineShoulder and the wrists their offsets in the group's own frame.
    """
    parents = [max(p, 0) for p in PARENTS]
    lengths = np.linalg.norm(joints - joints[:, parents], axis=2)  # (P, 25)
    lengths = np.where(np.isfinite(lengths), lengths, _DEFAULT_LENGTHS)
    offsets = lengths[..., None] * _REST_DIRECTIONS
    offsets[:, 0] = 0.0
    for j, (primary, (first, second), axis, secondary) in GROUP_FRAMES.items():
        children = list(CHILDREN[j])
        rest_frame = _frames(np.array(axis, dtype=np.float64),
                             np.array(secondary, dtype=np.float64))[0]  # fmt: skip
        vectors = joints[:, children] - joints[:, j, None]  # (P, C, 3)
        frame, ok = _frames(joints[:, primary] - joints[:, j], joints[:, second] - joints[:, first])
        ok &= np.isfinite(vectors).all(axis=(1, 2))
        shaped = np.einsum("pci,pik,lk->pcl", vectors, frame, rest_frame)
        offsets[:, children] = np.where(ok[:, None, None], shaped, offsets[:, children])
    return offsets


@dataclass(frozen=True, slots=True)
class _Step:
    """Nodes of one depth and one kind, solved together (all persons, all these nodes).

    kind: ``kabsch`` (several children), ``swing`` (a helper, or one child without a twist
    pair), ``twist`` (one child with a twist pair), ``leaf`` (no child: the parent's rotation).
    children: (K, C) the bones' end joints (``kabsch`` pads with -1; one column otherwise).
    """

    kind: str
    nodes: tuple[int, ...]
    parents: tuple[int, ...]
    joints: tuple[int, ...]
    children: npt.NDArray[np.intp]


def _schedule() -> tuple[_Step, ...]:
    """The rig's nodes by depth (a node's parent is solved at a smaller depth) and kind."""
    depth: list[int] = []
    groups: dict[tuple[int, str], list[tuple[int, tuple[int, ...]]]] = {}
    for n, node in enumerate(NODES):
        depth.append(0 if node.parent < 0 else depth[node.parent] + 1)
        children = CHILDREN[node.joint]
        kind: str
        ends: tuple[int, ...]
        if node.child is not None:
            kind, ends = "swing", (node.child,)
        elif not children:
            kind, ends = "leaf", ()
        elif len(children) >= 2:
            kind, ends = "kabsch", children
        else:
            kind, ends = ("twist" if node.joint in TWIST_PAIRS else "swing"), children
        groups.setdefault((depth[n], kind), []).append((n, ends))
    steps = []
    for (_, kind), members in sorted(groups.items(), key=lambda item: item[0][0]):
        width = max(1, *(len(bone_ends) for _, bone_ends in members))
        padded = np.full((len(members), width), -1, dtype=np.intp)
        for k, (_, bone_ends) in enumerate(members):
            padded[k, : len(bone_ends)] = bone_ends
        nodes = tuple(n for n, _ in members)
        steps.append(
            _Step(
                kind,
                nodes,
                tuple(NODES[n].parent for n in nodes),
                tuple(NODES[n].joint for n in nodes),
                padded,
            )
        )
    return tuple(steps)


_STEPS: Final = _schedule()


def node_rotations(joints: F64, offsets: F64) -> F64:
    """Global rotation (P, nodes, 3, 3) of every BVH node, the rig's solver at one instant.

    ``bvh_rig.global_rotations`` of a one-frame take (no previous frame: a node without data
    takes its parent's rotation), for P persons at once; the nodes of one depth and kind are
    solved together (:data:`_STEPS`), which is what makes it fast (numpy calls cost by the call).

    Args:
        joints: (P, 25, 3) metres, NaN where unknown.
        offsets: (P, 25, 3) from :func:`rest_offsets`.
    """
    persons = joints.shape[0]
    current = np.tile(np.eye(3), (persons, len(NODES), 1, 1))
    finite = np.asarray(np.isfinite(joints).all(axis=2))  # (P, 25)
    recon = np.full_like(joints, np.nan)
    recon[:, 0] = np.where(finite[:, 0, None], joints[:, 0], 0.0)
    for step in _STEPS:
        nodes = list(step.nodes)
        parent_rot = current[:, list(step.parents)]  # (P, K, 3, 3)
        if min(step.parents) < 0:  # the root's missing parent: the identity (before any frame)
            parent_rot = np.where(np.array(step.parents)[:, None, None] >= 0, parent_rot, _EYE)
        if step.kind == "leaf":
            current[:, nodes] = parent_rot
            continue
        base = recon[:, list(step.joints)]  # (P, K, 3)
        if step.kind == "kabsch":
            current[:, nodes] = _kabsch_step(step, joints, finite, offsets, base, parent_rot)
            continue
        c = step.children[:, 0]
        vector = joints[:, c] - base
        valid = _aimable(finite[:, c], vector)  # (P, K)
        offset = offsets[:, c]
        swing = _align(_rotate(parent_rot, offset), vector) @ parent_rot
        if step.kind == "twist":
            swing = _twist(step, joints, finite, offsets, vector, swing)
        rotation = np.where(valid[..., None, None], swing, parent_rot)
        current[:, nodes] = rotation
        recon[:, c] = base + _rotate(rotation, offset)
    return current


def _rotate(rotation: F64, vector: F64) -> F64:
    """Vectors (..., 3) rotated by matrices (..., 3, 3)."""
    rotated: F64 = (rotation @ vector[..., None])[..., 0]
    return rotated


def _kabsch_step(
    step: _Step, joints: F64, finite: npt.NDArray[np.bool_], offsets: F64, base: F64,
    parent_rot: F64,
) -> F64:  # fmt: skip
    """Joints with several children: the best fit of the children that have data (at least
    two), else the parent's rotation."""
    ends = np.maximum(step.children, 0)  # (K, C); -1 pads
    vectors = joints[:, ends] - base[:, :, None]  # (P, K, C, 3)
    valid = _aimable(finite[:, ends], vectors) & (step.children >= 0)
    persons, count = base.shape[:2]
    fitted = _kabsch(
        offsets[:, ends].reshape(persons * count, -1, 3),
        vectors.reshape(persons * count, -1, 3),
        valid.reshape(persons * count, -1),
    ).reshape(persons, count, 3, 3)
    rotation: F64 = np.where((valid.sum(axis=2) >= 2)[..., None, None], fitted, parent_rot)
    return rotation


def _aimable(finite: npt.NDArray[np.bool_], vector: F64) -> npt.NDArray[np.bool_]:
    """Where a bone has data and a direction (as the rig tests it)."""
    with np.errstate(invalid="ignore"):
        long_enough = _norm(vector) > _EPS_M
    ok: npt.NDArray[np.bool_] = finite & long_enough
    return ok


def _twist(
    step: _Step, joints: F64, finite: npt.NDArray[np.bool_], offsets: F64, vector: F64,
    swing: F64,
) -> F64:  # fmt: skip
    """The bone's frame with its twist from the grandchild pair, where the pair has data and
    spans a plane with the bone; elsewhere the swing."""
    first = [TWIST_PAIRS[j][0] for j in step.joints]
    second = [TWIST_PAIRS[j][1] for j in step.joints]
    c = step.children[:, 0]
    rest_frame, rest_ok = _frames(offsets[:, c], offsets[:, second] - offsets[:, first])
    now_frame, now_ok = _frames(vector, joints[:, second] - joints[:, first])
    ok = finite[:, first] & finite[:, second] & rest_ok & now_ok
    twisted = now_frame @ np.swapaxes(rest_frame, -1, -2)
    result: F64 = np.where(ok[..., None, None], twisted, swing)
    return result


def _align(a: F64, b: F64) -> F64:
    """The smallest rotations (..., 3, 3) taking directions ``a`` (..., 3) onto ``b`` (..., 3).

    Rodrigues' formula ``c·I + [v]× + v vᵀ / (1 + c)`` with ``v = a × b``, ``c = a · b`` (the
    rig's ``I + [v]× + [v]×² / (1 + c)``, the same matrix).
    """
    a = a / _norm(a)[..., None]
    b = b / _norm(b)[..., None]
    v = _cross(a, b)
    c = (a * b).sum(axis=-1)
    skew = (v @ _SKEW).reshape(*v.shape, 3)
    rotation = (
        c[..., None, None] * _EYE
        + skew
        + v[..., :, None] * (v / (1.0 + c)[..., None])[..., None, :]
    )
    opposite = c < -1.0 + 1e-9
    if opposite.any():  # half a turn about an axis normal to a (the rig's choice of axis)
        axis = _cross(a, np.array([1.0, 0.0, 0.0]))
        short = _norm(axis) < 1e-6
        axis = np.where(short[..., None], _cross(a, np.array([0.0, 1.0, 0.0])), axis)
        axis /= _norm(axis)[..., None]
        flip = 2.0 * axis[..., :, None] * axis[..., None, :] - _EYE
        rotation = np.where(opposite[..., None, None], flip, rotation)
    result: F64 = rotation
    return result


_SKEW: Final = np.zeros((3, 9))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # [v]×[i, k] = Σ_j ε_ijk v_j
    _SKEW[_j, 3 * _i + _k] = 1.0
    _SKEW[_j, 3 * _k + _i] = -1.0
_NEXT: Final = np.array([1, 2, 0], dtype=np.intp)
_AFTER: Final = np.array([2, 0, 1], dtype=np.intp)


def _cross(a: F64, b: F64) -> F64:
    """Row-wise cross products of (..., 3) vectors (``np.cross`` costs ten times as much)."""
    crossed: F64 = a[..., _NEXT] * b[..., _AFTER] - a[..., _AFTER] * b[..., _NEXT]
    return crossed


def _norm(v: F64) -> F64:
    """Row-wise lengths of (..., 3) vectors."""
    length: F64 = np.sqrt((v * v).sum(axis=-1))
    return length


def _frames(primary: F64, secondary: F64) -> tuple[F64, npt.NDArray[np.bool_]]:
    """Orthonormal frames (..., 3, 3), columns: primary, secondary made normal to it, their
    cross; and where they exist (the secondary not along the primary). Vectors: (..., 3)."""
    e1 = primary / _norm(primary)[..., None]
    s = secondary - (secondary * e1).sum(axis=-1)[..., None] * e1
    norm = _norm(s)
    ok = norm >= _EPS_M * np.maximum(1.0, _norm(secondary))
    e2 = s / norm[..., None]
    frame = np.stack([e1, e2, _cross(e1, e2)], axis=-1)
    return frame, np.asarray(ok & np.isfinite(frame).all(axis=(-2, -1)))


def _kabsch(src: F64, dst: F64, valid: npt.NDArray[np.bool_]) -> F64:
    """Per person, the proper rotation (P, 3, 3) taking the valid ``src`` vectors (P, C, 3) onto
    ``dst`` (``protocol.transform.kabsch_rotation`` over each person's valid rows)."""
    mask = valid[..., None]
    h = np.einsum("pci,pcj->pij", np.where(mask, src, 0.0), np.where(mask, dst, 0.0))
    u, _, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, 1, 2)
    ut = np.swapaxes(u, 1, 2)
    sign = np.sign(np.linalg.det(v @ ut))
    fix = np.tile(np.eye(3), (src.shape[0], 1, 1))
    fix[:, 2, 2] = np.where(sign == 0, 1.0, sign)
    rotation: F64 = v @ fix @ ut
    return rotation
