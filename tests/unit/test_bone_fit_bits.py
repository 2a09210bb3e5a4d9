"""The bone fit's vectorised forms give the bits of the plain algorithm they replaced.

The references below are the bone fit as it was written before it was vectorised (one gather
per bone group and end, the walk by depth levels); fusion's output (the golden replay digests)
depends on every bit, so the fast forms are checked against them on random skeletons with
unknown joints, zero-length bones, unknown references and mobilities.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion.anatomy import CHAIN_LEVELS
from skelfuse.fusion.bones import BONE_GROUPS, enforce_bone_lengths, project_bone_lengths
from skelfuse.protocol.skeleton import BONES

FloatArray = npt.NDArray[np.float64]
PARENT = np.array([p for p, _ in BONES])
CHILD = np.array([c for _, c in BONES])


def plain_enforce(original: FloatArray, ref: FloatArray) -> FloatArray:
    offsets = original[..., CHILD, :] - original[..., PARENT, :]
    norms = np.sqrt(np.vecdot(offsets, offsets))
    scale = np.isfinite(ref) & np.isfinite(norms) & (norms > 1e-9)
    with np.errstate(invalid="ignore", divide="ignore"):
        factors = ref / norms
        offset_of = np.empty(original.shape)
        offset_of[..., CHILD, :] = np.where(scale[..., None], offsets * factors[..., None], offsets)
    out = original.copy()
    for children, parents in CHAIN_LEVELS:
        hung = np.isfinite(out[..., parents, :]).all(axis=-1, keepdims=True)
        out[..., children, :] = np.where(
            hung, out[..., parents, :] + offset_of[..., children, :], out[..., children, :]
        )
    return out


def plain_project(
    original: FloatArray, ref: FloatArray, mobility: FloatArray | None, iterations: int
) -> FloatArray:
    missing = np.asarray(~np.isfinite(original).all(axis=-1))
    out = np.where(missing[..., None], 0.0, original)
    move = np.maximum(np.ones(out.shape[:-1]) if mobility is None else mobility, 1e-6)
    plan = []
    for group in BONE_GROUPS:
        parents, children = PARENT[group], CHILD[group]
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
    return plain_enforce(out, ref)


@pytest.mark.parametrize("seed", range(4))
def test_the_fast_bone_fits_give_the_plain_algorithms_bits(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for trial in range(150):
        persons = int(rng.integers(1, 8))
        joints = rng.normal(size=(persons, 25, 3)) * 0.3
        if trial % 3 == 0:
            joints[rng.random((persons, 25)) < 0.1] = np.nan
        if trial % 5 == 0:
            joints[:, 3] = joints[:, 2]  # a zero-length bone
        ref = rng.uniform(0.05, 0.5, size=(persons, 24))
        ref[rng.random((persons, 24)) < 0.1] = np.nan
        mobility = rng.uniform(0, 1, size=(persons, 25)) if trial % 2 else None
        iterations = trial % 4
        fast = project_bone_lengths(joints, ref, mobility, iterations)
        assert fast.tobytes() == plain_project(joints, ref, mobility, iterations).tobytes()
        assert enforce_bone_lengths(joints, ref).tobytes() == plain_enforce(joints, ref).tobytes()
        one = enforce_bone_lengths(joints[0], ref[0])
        assert one.tobytes() == plain_enforce(joints[0], ref[0]).tobytes()
