"""A rigid BVH rig fitted to fused joints: the rest skeleton and each frame's joint rotations.

Joint positions do not fix bone twist, and BVH stores rotations, so :mod:`recording.export_bvh`
asks this module for:

1. a **rest skeleton** (T-pose, facing +Z, Y up) whose bone lengths are the person's median
   fused bone lengths (:func:`rest_offsets`);
2. per frame, the global rotation of every node, walking the hierarchy from the root and
   giving each joint the rotation that takes its children's rest offsets onto the fused
   positions, aiming from the *reconstructed* position of the joint (so errors do not add up
   along a chain) (:func:`global_rotations`):
   - joints with several children (SpineBase, SpineShoulder, the wrists) get the best-fit
     rotation of all child offsets (Kabsch), which fixes their twist;
   - a joint with one child gets the swing that aligns the bone, and its twist from the pair of
     grandchildren where one exists (SpineMid from the shoulders, the elbows from hand and
     thumb, i.e. forearm pronation); elsewhere it inherits its parent's twist;
   - a joint with no fused data in a frame keeps its previous rotation.

Every child of a joint with several children hangs from its own zero-length helper node
(:data:`NODES`), so each bone's direction is free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import (
    CHILDREN,
    JOINT_COUNT,
    JOINT_NAMES,
    MIRROR_PERMUTATION,
    PARENTS,
    JointId,
)
from skelfuse.protocol.transform import kabsch_rotation

F64 = npt.NDArray[np.float64]
J = JointId

_S = 2**-0.5
REST_DIRECTIONS: dict[int, tuple[float, float, float]] = {
    J.SPINE_MID: (0, 1, 0), J.SPINE_SHOULDER: (0, 1, 0), J.NECK: (0, 1, 0), J.HEAD: (0, 1, 0),
    J.SHOULDER_LEFT: (1, 0, 0), J.ELBOW_LEFT: (1, 0, 0), J.WRIST_LEFT: (1, 0, 0),
    J.HAND_LEFT: (1, 0, 0), J.HAND_TIP_LEFT: (1, 0, 0), J.THUMB_LEFT: (_S, 0, _S),
    J.SHOULDER_RIGHT: (-1, 0, 0), J.ELBOW_RIGHT: (-1, 0, 0), J.WRIST_RIGHT: (-1, 0, 0),
    J.HAND_RIGHT: (-1, 0, 0), J.HAND_TIP_RIGHT: (-1, 0, 0), J.THUMB_RIGHT: (-_S, 0, _S),
    J.HIP_LEFT: (1, 0, 0), J.KNEE_LEFT: (0, -1, 0), J.ANKLE_LEFT: (0, -1, 0),
    J.FOOT_LEFT: (0, 0, 1),
    J.HIP_RIGHT: (-1, 0, 0), J.KNEE_RIGHT: (0, -1, 0), J.ANKLE_RIGHT: (0, -1, 0),
    J.FOOT_RIGHT: (0, 0, 1),
}  # fmt: skip
"""Unit direction of each bone (parent → joint) in the rest pose: T-pose facing +Z, left = +X."""

TWIST_PAIRS: dict[int, tuple[int, int]] = {
    J.SPINE_MID: (J.SHOULDER_RIGHT, J.SHOULDER_LEFT),
    J.ELBOW_LEFT: (J.HAND_LEFT, J.THUMB_LEFT),
    J.ELBOW_RIGHT: (J.HAND_RIGHT, J.THUMB_RIGHT),
}
"""Single-child joints whose twist comes from the vector between two grandchildren."""

DEFAULT_BONE_M: dict[int, float] = {
    J.SPINE_MID: 0.25, J.SPINE_SHOULDER: 0.25, J.NECK: 0.07, J.HEAD: 0.12,
    J.SHOULDER_LEFT: 0.17, J.ELBOW_LEFT: 0.28, J.WRIST_LEFT: 0.25, J.HAND_LEFT: 0.07,
    J.HAND_TIP_LEFT: 0.08, J.THUMB_LEFT: 0.06, J.HIP_LEFT: 0.08, J.KNEE_LEFT: 0.42,
    J.ANKLE_LEFT: 0.40, J.FOOT_LEFT: 0.12,
}  # fmt: skip
"""Fallback bone lengths (metres) for a bone never seen in the take; right = left."""


def _default_length(joint: int) -> float:
    """A right-side bone takes its left counterpart's length."""
    return DEFAULT_BONE_M[joint if joint in DEFAULT_BONE_M else MIRROR_PERMUTATION[joint]]


GROUP_FRAMES: dict[int, tuple[int, tuple[int, int], tuple[float, float, float],
                               tuple[float, float, float]]] = {
    J.SPINE_BASE: (J.SPINE_MID, (J.HIP_RIGHT, J.HIP_LEFT), (0, 1, 0), (1, 0, 0)),
    J.SPINE_SHOULDER: (J.NECK, (J.SHOULDER_RIGHT, J.SHOULDER_LEFT), (0, 1, 0), (1, 0, 0)),
    J.WRIST_LEFT: (J.HAND_LEFT, (J.HAND_LEFT, J.THUMB_LEFT), (1, 0, 0), (0, 0, 1)),
    J.WRIST_RIGHT: (J.HAND_RIGHT, (J.HAND_RIGHT, J.THUMB_RIGHT), (-1, 0, 0), (0, 0, 1)),
}  # fmt: skip
"""Joints with several children: (primary child, secondary pair, rest primary axis, rest
secondary axis). Their children's rest offsets keep the person's own median geometry (pelvis,
shoulder girdle, hand), expressed in a frame built from the primary bone and the pair."""


def rest_offsets(joints: F64) -> F64:
    """Rest-pose offsets (25, 3) in metres from (T, 25, 3) positions.

    Single bones: median length along :data:`REST_DIRECTIONS`. Children of the joints in
    :data:`GROUP_FRAMES`: the median of their offsets in the group's own frame, so the rest
    pelvis, shoulder girdle and hand have the person's shape and fit every frame by rotation.
    """
    joints = np.asarray(joints, dtype=np.float64)
    offsets = np.zeros((JOINT_COUNT, 3))
    for child, parent in enumerate(PARENTS):
        if parent < 0:
            continue
        lengths = np.linalg.norm(joints[:, child] - joints[:, parent], axis=1)
        lengths = lengths[np.isfinite(lengths)]
        length = float(np.median(lengths)) if lengths.size else _default_length(child)
        offsets[child] = length * np.asarray(REST_DIRECTIONS[child], dtype=np.float64)
    for j, (primary, (first, second), axis, secondary) in GROUP_FRAMES.items():
        children = CHILDREN[j]
        rest_frame = _frame(np.asarray(axis, dtype=np.float64),
                            np.asarray(secondary, dtype=np.float64))  # fmt: skip
        assert rest_frame is not None
        local: list[F64] = []
        for pose in joints:
            vectors = pose[list(children)] - pose[j]
            frame = _frame(pose[primary] - pose[j], pose[second] - pose[first])
            if frame is None or not np.isfinite(vectors).all():
                continue
            local.append(vectors @ frame)
        if local:
            offsets[list(children)] = np.median(np.stack(local), axis=0) @ rest_frame.T
    return offsets


# --- rotations ---------------------------------------------------------------------------------


def _align(a: F64, b: F64) -> F64:
    """The smallest rotation taking direction ``a`` onto direction ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-9:
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    rotation: F64 = np.eye(3) + vx + vx @ vx / (1.0 + c)
    return rotation


def _frame(primary: F64, secondary: F64) -> F64 | None:
    e1 = primary / np.linalg.norm(primary)
    s = secondary - np.dot(secondary, e1) * e1
    norm = np.linalg.norm(s)
    if norm < 1e-6 * max(1.0, float(np.linalg.norm(secondary))):
        return None
    e2 = s / norm
    return np.column_stack([e1, e2, np.cross(e1, e2)])


def _finite(v: F64) -> bool:
    return bool(np.isfinite(v).all())


@dataclass(frozen=True, slots=True)
class Node:
    """One BVH joint: a skeleton joint, or a zero-length helper carrying one child's bone."""

    name: str
    parent: int
    joint: int
    """The skeleton joint this node sits on (a helper sits on its parent joint)."""
    child: int | None = None
    """For a helper: the skeleton joint whose bone it carries."""


def _build_nodes() -> tuple[tuple[Node, ...], tuple[int, ...]]:
    """BVH nodes in file (depth-first) order and, per skeleton joint, its node index."""
    nodes: list[Node] = []
    node_of = [-1] * JOINT_COUNT

    def visit(j: int, parent_node: int) -> None:
        node_of[j] = len(nodes)
        nodes.append(Node(JOINT_NAMES[j], parent_node, j))
        here = node_of[j]
        group = len(CHILDREN[j]) >= 2
        for c in CHILDREN[j]:
            if group:
                helper = len(nodes)
                nodes.append(Node(f"{JOINT_NAMES[j]}_{JOINT_NAMES[c]}", here, j, c))
                visit(c, helper)
            else:
                visit(c, here)

    visit(0, -1)
    return tuple(nodes), tuple(node_of)


NODES, NODE_OF = _build_nodes()
"""Every child of a joint with several children (SpineBase, SpineShoulder, the wrists) hangs
from its own zero-length helper joint, so each bone's direction is free: Kinect's pelvis,
shoulder girdle and hand are not rigid (the spine bends, shoulders shrug, thumbs move) and one
rotation cannot fit all of their children."""


def global_rotations(joints: F64, offsets: F64) -> tuple[F64, F64]:
    """Per-frame global rotations of every node (T, nodes, 3, 3) and root positions (T, 3).

    Args:
        joints: (T, 25, 3) fused positions, metres, NaN where unknown.
        offsets: (25, 3) rest offsets from :func:`rest_offsets`.
    """
    frames = joints.shape[0]
    count = len(NODES)
    rotations = np.tile(np.eye(3), (frames, count, 1, 1))
    roots = np.zeros((frames, 3))
    previous = np.tile(np.eye(3), (count, 1, 1))
    previous_root = next((f[0].copy() for f in joints if _finite(f[0])), np.zeros(3))
    for f in range(frames):
        target = joints[f]
        root = target[0] if _finite(target[0]) else previous_root
        recon = np.full((JOINT_COUNT, 3), np.nan)
        recon[0] = root
        current = previous.copy()
        for n, node in enumerate(NODES):
            j = node.joint
            parent_rot = current[node.parent] if node.parent >= 0 else previous[n]
            base = recon[j]
            if node.child is not None:  # helper: aims one bone, twist from its joint
                c = node.child
                if _finite(target[c]) and np.linalg.norm(target[c] - base) > 1e-6:
                    current[n] = _align(parent_rot @ offsets[c], target[c] - base) @ parent_rot
                else:
                    current[n] = parent_rot @ previous[node.parent].T @ previous[n]
                recon[c] = base + current[n] @ offsets[c]
                continue
            children = CHILDREN[j]
            if not children:
                current[n] = parent_rot
                continue
            valid = [c for c in children if _finite(target[c]) and np.linalg.norm(
                target[c] - base) > 1e-6]  # fmt: skip
            if len(children) >= 2 and len(valid) >= 2:
                rest = np.stack([offsets[c] for c in valid])
                now = np.stack([target[c] - base for c in valid])
                current[n] = kabsch_rotation(rest, now)
            elif len(children) == 1 and valid:
                current[n] = _single_child_rotation(j, valid[0], target, base, offsets, parent_rot)
            elif node.parent >= 0:
                current[n] = parent_rot @ previous[node.parent].T @ previous[n]
            else:
                current[n] = previous[n]
            if len(children) == 1:
                recon[children[0]] = base + current[n] @ offsets[children[0]]
        rotations[f] = current
        roots[f] = root
        previous = current
        previous_root = root
    return rotations, roots


def _single_child_rotation(
    j: int, c: int, target: F64, base: F64, offsets: F64, parent_rot: F64
) -> F64:
    """Swing onto the bone; twist from the grandchild pair, else the parent's twist."""
    vector = target[c] - base
    if j in TWIST_PAIRS:
        first, second = TWIST_PAIRS[j]
        if _finite(target[first]) and _finite(target[second]):
            rest_frame = _frame(offsets[c], offsets[second] - offsets[first])
            now_frame = _frame(vector, target[second] - target[first])
            if rest_frame is not None and now_frame is not None:
                rotation: F64 = now_frame @ rest_frame.T
                return rotation
    swing: F64 = _align(parent_rot @ offsets[c], vector) @ parent_rot
    return swing
