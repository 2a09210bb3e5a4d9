"""BVH export of fused skeletons, and the round trip that checks it.

The rig (rest skeleton and per-frame rotations) is fitted by :mod:`recording.bvh_rig`; this
module turns it into a :mod:`protocol.bvh` file: Euler angles in ``Zrotation Xrotation
Yrotation`` order (local = Rz·Rx·Ry), offsets and root translation in **centimetres**, Y up, at
a fixed frame rate (fused frames resampled).

Leaf joints (Head, hand tips, thumbs, feet) are written as joints with zero rotation and a short
End Site so that every one of the 25 joints has a named position in the file.

Reading the file back (:func:`bvh_positions_m`) gives positions within the fused joints' own
bone-length jitter of the input (``docs/benchmarks.md``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.bvh import Bvh, BvhJoint, format_bvh, forward_kinematics, parse_bvh
from skelfuse.protocol.skeleton import CHILDREN, JOINT_COUNT, JOINT_NAMES, JointId
from skelfuse.recording.bvh_rig import NODES, REST_DIRECTIONS, global_rotations, rest_offsets
from skelfuse.recording.take import PersonTrack, TakeError, resample

F64 = npt.NDArray[np.float64]
CM_PER_M = 100.0

_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
_ROT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")


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

    ``stretch``: also give every joint position channels carrying its per-frame local
    translation (the full translation from its parent, which replaces OFFSET as the BVH
    convention says; OFFSET stays the rest bone), so the file reproduces the fused joints
    exactly (analysis tools); default rigid bones (animation tools), which reproduce them within
    the fused bone-length jitter.

    Raises:
        TakeError: ``joints`` is not (T >= 1, 25, 3).
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
    columns = [roots * CM_PER_M, angles[:, 0]]
    if stretch:
        translations = _translations(joints, offsets, rotations, roots)
        for n in range(1, len(NODES)):
            if _stretchable(n):
                columns.append(translations[:, n] * CM_PER_M)
            columns.append(angles[:, n])
    else:
        columns.append(angles[:, 1:].reshape(joints.shape[0], -1))
    motion = np.concatenate(columns, axis=1)
    return format_bvh(Bvh(_hierarchy(offsets, stretch), 1.0 / fps, fps, motion))


def _hierarchy(offsets: F64, stretch: bool) -> tuple[BvhJoint, ...]:
    """The rig's nodes as BVH joints (centimetres), an End Site after each leaf."""
    joints: list[BvhJoint] = []
    index_of: dict[int, int] = {}
    for n, node in enumerate(NODES):
        channels: tuple[str, ...]
        if node.parent < 0:
            channels, offset = _ROOT_CHANNELS, np.zeros(3)
        else:
            channels = _ROOT_CHANNELS if stretch and _stretchable(n) else _ROT_CHANNELS
            offset = np.zeros(3) if node.child is not None else offsets[node.joint] * CM_PER_M
        index_of[n] = len(joints)
        parent = index_of[node.parent] if node.parent >= 0 else -1
        joints.append(BvhJoint(node.name, parent, offset, channels))
        if not any(other.parent == n for other in NODES):
            j = node.joint
            direction = np.asarray(REST_DIRECTIONS.get(j, (0.0, 1.0, 0.0)), dtype=np.float64)
            end = direction * (5.0 if j == JointId.HEAD else 2.0)
            joints.append(BvhJoint(f"{node.name}.end", index_of[n], end, end_site=True))
    return tuple(joints)


def _stretchable(n: int) -> bool:
    node = NODES[n]
    return node.parent >= 0 and node.child is None


def _translations(joints: F64, offsets: F64, rotations: F64, roots: F64) -> F64:
    """Per-frame local translations (T, nodes, 3), metres, in the parent node's frame, that put
    each stretchable joint exactly on its fused position: what its position channels carry (the
    BVH convention: the channels replace OFFSET). Where the joint is unknown it keeps its last
    known translation (the rest offset before the first), as its rotation is kept."""
    frames = joints.shape[0]
    translations = np.zeros((frames, len(NODES), 3))
    positions = np.zeros((frames, JOINT_COUNT, 3))
    positions[:, 0] = roots
    for n, node in enumerate(NODES):
        if not _stretchable(n):
            continue
        j, parent_joint = node.joint, NODES[node.parent].joint
        parent_rot = rotations[:, node.parent]
        base = positions[:, parent_joint]
        wanted = np.einsum("fji,fj->fi", parent_rot, joints[:, j] - base)
        known = np.isfinite(wanted).all(axis=1)
        held = np.vstack([offsets[j], wanted[known]])  # row k: the k-th known frame's
        translations[:, n] = held[np.cumsum(known)]
        positions[:, j] = base + np.einsum("fij,fj->fi", parent_rot, translations[:, n])
    return translations


def export_bvh(
    track: PersonTrack, path: str | Path | None = None, fps: float = 30.0, *, stretch: bool = False
) -> BvhExport:
    """Export one person to BVH (resampled to ``fps``); writes ``path`` when given."""
    _, joints, _ = resample(track, fps)
    text = bvh_from_joints(joints, fps, stretch=stretch)
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return BvhExport(text, joints.shape[0], fps, joints)


# --- reading back ------------------------------------------------------------------------------


def bvh_positions_m(text: str, names: Sequence[str] = JOINT_NAMES) -> F64:
    """Read BVH text written by :func:`bvh_from_joints`; (N, len(names), 3) metres.

    Raises:
        BvhError: the text is not a BVH file.
        KeyError: a name is not a joint of the file.
    """
    bvh = parse_bvh(text)
    positions = forward_kinematics(bvh) / CM_PER_M
    selected: F64 = positions[:, [bvh.index(n) for n in names]]
    return selected


def roundtrip_errors_m(joints: F64, text: str) -> F64:
    """Per-joint distances (metres) between ``joints`` and the FK of ``text``, finite only."""
    recon = bvh_positions_m(text)
    errors = np.linalg.norm(recon - joints, axis=-1)
    finite: F64 = errors[np.isfinite(errors)]
    return finite
