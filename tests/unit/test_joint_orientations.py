"""Joint orientations for the feed: the BVH rig's solver at one instant, as quaternions, that
an avatar's forward kinematics turns back into the fused positions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.sim.mocap import load_asf_amc, load_bvh
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.geometry.quaternion import (
    matrix_to_quaternion,
    quaternion_multiply,
    quaternion_rotate,
)
from skelfuse.protocol.skeleton import JOINT_COUNT, PARENTS
from skelfuse.protocol.transform import axis_rotation
from skelfuse.recording import bvh_rig
from skelfuse.recording.joint_orientations import (
    BONE_NODE,
    node_rotations,
    orientations,
    rest_offsets,
)


def forward_kinematics(root: np.ndarray, local: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """An avatar's FK, as docs/api.md states it: positions (25, 3) from the root position,
    the local rotations (25, 4) and the rest offsets (25, 3)."""
    world = np.zeros((JOINT_COUNT, 4))
    positions = np.zeros((JOINT_COUNT, 3))
    done: set[int] = set()
    while len(done) < JOINT_COUNT:  # SpineShoulder (20) comes after its children
        for j, parent in enumerate(PARENTS):
            if j in done or (parent >= 0 and parent not in done):
                continue
            if parent < 0:
                world[j], positions[j] = local[j], root
            else:
                world[j] = quaternion_multiply(world[parent], local[j])
                positions[j] = positions[parent] + quaternion_rotate(world[j], offsets[j])
            done.add(j)
    return positions


def chain_known(joints: np.ndarray) -> np.ndarray:
    """(25,) whether a joint and every joint up to the root are known: FK gives those back
    exactly; below an unknown joint, bones take the rig's default lengths."""
    finite = np.isfinite(joints).all(axis=1)
    known = finite.copy()
    for _ in range(JOINT_COUNT):
        known = finite & np.array([p < 0 or known[p] for p in PARENTS])
    return known


def _noisy_routine(persons: int, seconds: float, seed: int) -> np.ndarray:
    performer = ProceduralPerformer(persons)
    frames = np.stack([performer.joints_at(t) for t in np.arange(0.0, seconds, 0.2)])
    rng = np.random.default_rng(seed)
    return frames + rng.normal(scale=0.01, size=frames.shape)


def test_the_rig_solver_at_one_instant_for_every_person_at_once() -> None:
    frames = _noisy_routine(3, 27.0, seed=0)
    rng = np.random.default_rng(1)
    frames[rng.random(frames.shape[:3]) < 0.08] = np.nan  # joints lost here and there
    frames[5, 1] = np.nan  # a whole person lost
    for frame in frames:
        offsets = rest_offsets(frame)
        nodes = node_rotations(frame, offsets)
        for person in range(frame.shape[0]):
            take = frame[person][None]
            expected_offsets = bvh_rig.rest_offsets(take)
            expected, _ = bvh_rig.global_rotations(take, expected_offsets)
            np.testing.assert_allclose(offsets[person], expected_offsets, atol=1e-12)
            np.testing.assert_allclose(nodes[person], expected[0], atol=1e-9)


def test_forward_kinematics_gives_the_positions_back_on_mocap(cmu_dir: Path) -> None:
    for clip in (load_bvh(cmu_dir / "scaled_131_01.bvh"),
                 load_asf_amc(cmu_dir / "02.asf", cmu_dir / "02_01.amc")):  # fmt: skip
        joints = clip.joints_m[::4]  # float32, as clips and sensors give them
        result = orientations(joints)
        worst = 0.0
        for t in range(joints.shape[0]):
            positions = forward_kinematics(joints[t, 0], result.local[t], result.rest_offsets[t])
            worst = max(worst, float(np.abs(positions - joints[t]).max()))
        assert worst < 0.005, f"{clip.name}: {worst * 1000:.2f} mm"


def test_world_is_parent_world_times_local() -> None:
    result = orientations(_noisy_routine(6, 10.0, seed=2).reshape(-1, JOINT_COUNT, 3))
    parents = [max(p, 0) for p in PARENTS]
    composed = quaternion_multiply(result.world[:, parents], result.local)
    composed[:, 0] = result.local[:, 0]
    same_sign = np.where(composed[..., 3:] < 0, -composed, composed)
    np.testing.assert_allclose(same_sign, result.world, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(result.world, axis=-1), 1.0, atol=1e-12)
    assert (result.world[..., 3] >= 0).all() and (result.local[..., 3] >= 0).all()


def test_the_rest_pose_has_no_rotation_and_a_turned_body_the_turn() -> None:
    offsets = 0.3 * np.array([bvh_rig.REST_DIRECTIONS.get(j, (0, 0, 0)) for j in range(25)])
    offsets[[12, 16]] = [[0.1, -0.05, 0.0], [-0.1, -0.05, 0.0]]  # hips a little below
    offsets[[4, 8]] = [[0.18, 0.0, 0.0], [-0.18, 0.0, 0.0]]  # shoulders
    rest = np.zeros((JOINT_COUNT, 3))
    for _ in range(JOINT_COUNT):  # settle every chain: SpineShoulder (20) follows its children
        for j, parent in enumerate(PARENTS):
            if parent >= 0:
                rest[j] = rest[parent] + offsets[j]
    turn = axis_rotation("y", 90.0)
    result = orientations(np.stack([rest, rest @ turn.T]))
    identity = np.tile([0.0, 0.0, 0.0, 1.0], (JOINT_COUNT, 1))
    np.testing.assert_allclose(result.world[0], identity, atol=1e-9)
    np.testing.assert_allclose(result.world[1], np.tile(matrix_to_quaternion(turn), (25, 1)),
                               atol=1e-9)  # fmt: skip
    np.testing.assert_allclose(result.local[1, 1:], identity[1:], atol=1e-9)


def test_matrix_to_quaternion_inverts_every_kind_of_rotation() -> None:
    rng = np.random.default_rng(3)
    angles = np.concatenate([rng.uniform(-np.pi, np.pi, 200), [0.0, np.pi, -np.pi, 1e-9]])
    axes = rng.normal(size=(angles.size, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    skew = np.cross(axes[:, None, :], -np.eye(3))  # [a]× per axis
    matrices = (
        np.eye(3) + np.sin(angles)[:, None, None] * skew
        + (1 - np.cos(angles))[:, None, None] * skew @ skew
    )  # fmt: skip
    q = matrix_to_quaternion(matrices)
    v = rng.normal(size=(angles.size, 3))
    np.testing.assert_allclose(quaternion_rotate(q, v), np.einsum("pij,pj->pi", matrices, v),
                               atol=1e-12)  # fmt: skip
    assert (q[:, 3] >= 0).all()


def test_bone_node_is_the_node_that_places_each_joint() -> None:
    assert BONE_NODE[0] == 0
    for j in range(1, JOINT_COUNT):
        node = bvh_rig.NODES[BONE_NODE[j]]
        assert node.child == j or (node.child is None and bvh_rig.NODES[
            bvh_rig.NODE_OF[j]].parent == BONE_NODE[j])  # fmt: skip


def test_a_bad_shape_is_refused() -> None:
    with pytest.raises(ValueError, match="joints must be"):
        orientations(np.zeros((24, 3)))
