"""BVH export of fused skeletons, and a BVH reader with forward kinematics to check it.

Joint positions do not fix bone twist, and BVH stores rotations, so the export:

1. fits a **rest skeleton** (T-pose, facing +Z, Y up) whose bone lengths are the person's median
   fused bone lengths;
2. per frame, walks the hierarchy from the root and gives each joint the global rotation that
   takes its children's rest offsets onto the fused positions, aiming from the *reconstructed*
   position of the joint (so errors do not add up along a chain):
   - joints with several children (SpineBase, SpineShoulder, the wrists) get the best-fit
     rotation of all child offsets (Kabsch), which fixes their twist;
   - a joint with one child gets the swing that aligns the bone, and its twist from the pair of
     grandchildren where one exists (SpineMid from the shoulders, the elbows from hand and
     thumb, i.e. forearm pronation); elsewhere it inherits its parent's twist;
   - a joint with no fused data in a frame keeps its previous rotation;
3. writes Euler angles in ``Zrotation Xrotation Yrotation`` order (local = Rz·Rx·Ry), offsets and
   root translation in **centimetres**, Y up, at a fixed frame rate (fused frames resampled).

Leaf joints (Head, hand tips, thumbs, feet) are written as joints with zero rotation and a short
End Site so that every one of the 25 joints has a named position in the file.

Reading the file back (:func:`read_bvh`) and running :func:`forward_kinematics` gives positions
within the fused joints' own bone-length jitter of the input (``docs/benchmarks.md``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, JOINT_NAMES, PARENTS, JointId
from skelfuse.recording.take import PersonTrack, TakeError, resample

F64 = npt.NDArray[np.float64]
J = JointId
CM_PER_M = 100.0

CHILDREN: tuple[tuple[int, ...], ...] = tuple(
    tuple(c for c in range(JOINT_COUNT) if PARENTS[c] == j) for j in range(JOINT_COUNT)
)
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

_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
_ROT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")


def _default_length(joint: int) -> float:
    name = JOINT_NAMES[joint].replace("Right", "Left")
    return DEFAULT_BONE_M[JointId[_enum_name(name)]]


def _enum_name(camel: str) -> str:
    out = "".join("_" + c if c.isupper() else c for c in camel).lstrip("_")
    return out.upper()


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


def _kabsch(rest: F64, current: F64) -> F64:
    """Rotation R minimising Σ|R·rest_i − current_i|² (rows are vectors)."""
    h = rest.T @ current
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation: F64 = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rotation


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
                current[n] = _kabsch(rest, now)
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


def euler_zxy_deg(rotation: F64) -> F64:
    """(..., 3, 3) rotation matrices → (..., 3) angles (z, x, y) in degrees, R = Rz·Rx·Ry."""
    r = rotation
    x = np.arcsin(np.clip(r[..., 2, 1], -1.0, 1.0))
    cx = np.cos(x)
    regular = np.abs(cx) > 1e-9
    z = np.where(regular, np.arctan2(-r[..., 0, 1], r[..., 1, 1]), np.arctan2(r[..., 1, 0],
                 r[..., 0, 0]))  # fmt: skip
    y = np.where(regular, np.arctan2(-r[..., 2, 0], r[..., 2, 2]), 0.0)
    angles: F64 = np.degrees(np.stack([z, x, y], axis=-1))
    return angles


def _axis_matrix(axis: str, degrees: F64) -> F64:
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    if axis == "X":
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == "Y":
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    return np.moveaxis(np.array(rows, dtype=np.float64), (0, 1), (-2, -1))


# --- writing -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class BvhExport:
    text: str
    frames: int
    fps: float
    joints_m: F64
    """(N, 25, 3) the resampled fused positions the BVH was computed from (NaN where unknown)."""


def bvh_from_joints(
    joints: F64, fps: float, offsets: F64 | None = None, *, stretch: bool = False
) -> str:
    """BVH text for (T, 25, 3) world positions (metres, Y up) sampled at ``fps``.

    ``stretch``: also give every bone position channels carrying its per-frame length change, so
    the file reproduces the fused joints exactly (analysis tools); default rigid bones
    (animation tools), which reproduce them within the fused bone-length jitter.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (JOINT_COUNT, 3):
        raise TakeError(f"expected (T, 25, 3) joints, got shape {joints.shape}")
    if joints.shape[0] == 0:
        raise TakeError("no frames to export")
    offsets = rest_offsets(joints) if offsets is None else offsets
    rotations, roots = global_rotations(joints, offsets)
    local = rotations.copy()
    for n, node in enumerate(NODES):
        if node.parent >= 0:
            local[:, n] = np.swapaxes(rotations[:, node.parent], -1, -2) @ rotations[:, n]
        if node.child is None and not CHILDREN[node.joint]:
            local[:, n] = np.eye(3)
    angles = euler_zxy_deg(local)
    stretches = _stretches(joints, offsets, rotations, roots) if stretch else None
    lines = ["HIERARCHY"]
    _write_node(lines, 0, offsets, 0, stretch)
    lines.append("MOTION")
    lines.append(f"Frames: {joints.shape[0]}")
    lines.append(f"Frame Time: {1.0 / fps:.8f}")
    for f in range(joints.shape[0]):
        if stretches is None:
            values = [*(roots[f] * CM_PER_M), *angles[f].reshape(-1)]
        else:
            values = [*(roots[f] * CM_PER_M), *angles[f, 0]]
            for n in range(1, len(NODES)):
                if _stretchable(n):
                    values.extend(stretches[f, n] * CM_PER_M)
                values.extend(angles[f, n])
        lines.append(" ".join(f"{v:.6f}" for v in values))
    return "\n".join(lines) + "\n"


def _stretchable(n: int) -> bool:
    node = NODES[n]
    return node.parent >= 0 and node.child is None


def _stretches(joints: F64, offsets: F64, rotations: F64, roots: F64) -> F64:
    """Per-frame offset changes (T, nodes, 3) in the parent node's frame that put each joint
    exactly on its fused position (zero where the joint is unknown)."""
    frames = joints.shape[0]
    deltas = np.zeros((frames, len(NODES), 3))
    positions = np.zeros((frames, JOINT_COUNT, 3))
    positions[:, 0] = roots
    for n, node in enumerate(NODES):
        if not _stretchable(n):
            continue
        j, parent_joint = node.joint, NODES[node.parent].joint
        parent_rot = rotations[:, node.parent]
        base = positions[:, parent_joint]
        wanted = np.einsum("fji,fj->fi", parent_rot, joints[:, j] - base) - offsets[j]
        known = np.isfinite(wanted).all(axis=1)
        deltas[known, n] = wanted[known]
        positions[:, j] = base + np.einsum("fij,fj->fi", parent_rot, offsets[j] + deltas[:, n])
    return deltas


def _write_node(lines: list[str], n: int, offsets: F64, depth: int, stretch: bool) -> None:
    node = NODES[n]
    pad = "  " * depth
    channels: tuple[str, ...]
    if node.parent < 0:
        lines.append(f"ROOT {node.name}")
        channels = _ROOT_CHANNELS
        offset = np.zeros(3)
    else:
        lines.append(f"{pad}JOINT {node.name}")
        channels = _ROOT_CHANNELS if stretch and _stretchable(n) else _ROT_CHANNELS
        offset = np.zeros(3) if node.child is not None else offsets[node.joint] * CM_PER_M
    lines.append(f"{pad}{{")
    lines.append(f"{pad}  OFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}")
    lines.append(f"{pad}  CHANNELS {len(channels)} {' '.join(channels)}")
    kids = [k for k, other in enumerate(NODES) if other.parent == n]
    for k in kids:
        _write_node(lines, k, offsets, depth + 1, stretch)
    if not kids:
        j = node.joint
        direction = np.asarray(REST_DIRECTIONS.get(j, (0.0, 1.0, 0.0)), dtype=np.float64)
        end = direction * (5.0 if j == J.HEAD else 2.0)
        lines.append(f"{pad}  End Site")
        lines.append(f"{pad}  {{")
        lines.append(f"{pad}    OFFSET {end[0]:.6f} {end[1]:.6f} {end[2]:.6f}")
        lines.append(f"{pad}  }}")
    lines.append(f"{pad}}}")


def export_bvh(
    track: PersonTrack, path: str | Path | None = None, fps: float = 30.0, *, stretch: bool = False
) -> BvhExport:
    """Export one person to BVH (resampled to ``fps``); writes ``path`` when given."""
    _, joints, _ = resample(track, fps)
    text = bvh_from_joints(joints, fps, stretch=stretch)
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return BvhExport(text, joints.shape[0], fps, joints)


# --- reading and forward kinematics ------------------------------------------------------------


class BvhError(ValueError):
    """A BVH file this reader cannot parse; the message gives the line."""


@dataclass
class BvhJoint:
    name: str
    parent: int
    offset: F64
    channels: list[str] = field(default_factory=list)


@dataclass
class Bvh:
    joints: list[BvhJoint]
    frame_time_s: float
    motion: F64
    """(N, channels) values in file order."""

    def index(self, name: str) -> int:
        for i, joint in enumerate(self.joints):
            if joint.name == name:
                return i
        raise KeyError(name)


def read_bvh(text: str) -> Bvh:
    """Parse BVH text (any channel order; End Sites are skipped)."""
    tokens = text.split()
    pos = 0
    joints: list[BvhJoint] = []
    stack: list[int] = []

    def take() -> str:
        nonlocal pos
        if pos >= len(tokens):
            raise BvhError("unexpected end of file")
        pos += 1
        return tokens[pos - 1]

    if take() != "HIERARCHY":
        raise BvhError("missing HIERARCHY")
    end_site_depth = 0
    while True:
        token = take()
        if token in ("ROOT", "JOINT"):
            joints.append(BvhJoint(take(), stack[-1] if stack else -1, np.zeros(3)))
        elif token == "End":
            take()  # "Site"
            end_site_depth = 1
        elif token == "{":
            if end_site_depth:
                end_site_depth += 1
            else:
                stack.append(len(joints) - 1)
        elif token == "}":
            if end_site_depth:
                end_site_depth = 0 if end_site_depth == 2 else end_site_depth - 1
            else:
                stack.pop()
        elif token == "OFFSET":
            offset = np.array([float(take()) for _ in range(3)])
            if not end_site_depth:
                joints[-1].offset = offset
        elif token == "CHANNELS":
            joints[-1].channels = [take() for _ in range(int(take()))]
        elif token == "MOTION":
            break
        else:
            raise BvhError(f"unexpected token {token!r}")
    if take() != "Frames:":
        raise BvhError("missing 'Frames:'")
    frames = int(take())
    if (take(), take()) != ("Frame", "Time:"):
        raise BvhError("missing 'Frame Time:'")
    frame_time = float(take())
    width = sum(len(j.channels) for j in joints)
    values = np.array([float(v) for v in tokens[pos:]], dtype=np.float64)
    if values.size != frames * width:
        raise BvhError(f"expected {frames}×{width} motion values, found {values.size}")
    return Bvh(joints, frame_time, values.reshape(frames, width))


def forward_kinematics(bvh: Bvh) -> F64:
    """Joint positions (N, joints, 3) in the file's units, in file joint order."""
    frames = bvh.motion.shape[0]
    count = len(bvh.joints)
    positions = np.zeros((frames, count, 3))
    rotations = np.zeros((frames, count, 3, 3))
    column = 0
    for i, joint in enumerate(bvh.joints):
        local_rot = np.tile(np.eye(3), (frames, 1, 1))
        translation = np.tile(joint.offset, (frames, 1))
        for channel in joint.channels:
            values = bvh.motion[:, column]
            column += 1
            if channel.endswith("position"):
                translation[:, "XYZ".index(channel[0])] += values
            elif channel.endswith("rotation"):
                local_rot = local_rot @ _axis_matrix(channel[0], values)
            else:
                raise BvhError(f"unknown channel {channel!r}")
        if joint.parent < 0:
            positions[:, i] = translation
            rotations[:, i] = local_rot
        else:
            parent_rot = rotations[:, joint.parent]
            positions[:, i] = positions[:, joint.parent] + np.einsum(
                "fij,fj->fi", parent_rot, translation
            )
            rotations[:, i] = parent_rot @ local_rot
    return positions


def bvh_positions_m(text: str, names: Sequence[str] = JOINT_NAMES) -> F64:
    """Read BVH text written by :func:`bvh_from_joints`; (N, len(names), 3) metres."""
    bvh = read_bvh(text)
    positions = forward_kinematics(bvh) / CM_PER_M
    return positions[:, [bvh.index(n) for n in names]]


def roundtrip_errors_m(joints: F64, text: str) -> F64:
    """Per-joint distances (metres) between ``joints`` and the FK of ``text``, finite only."""
    recon = bvh_positions_m(text)
    errors = np.linalg.norm(recon - joints, axis=-1)
    finite: F64 = errors[np.isfinite(errors)]
    return finite
