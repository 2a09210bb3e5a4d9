"""The bone fit against the plain algorithm, written in numpy below.

The references below are the bone fit as it was first written (one gather per bone group and
end, the walk by depth levels). The vectorised outward pass (enforce_bone_lengths) must give
their bits: it adds the same offsets in the same order. The projection's compiled loop must
agree within 1e-6 m, on random skeletons with unknown joints, zero-length bones, unknown
references and mobilities; its compilation is made once, whatever arrays it is given.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion import bone_fit
from skelfuse.fusion.anatomy import CHAIN_LEVELS
from skelfuse.fusion.bone_fit import BONE_GROUPS, enforce_bone_lengths, project_bone_lengths
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
        expected = plain_project(joints, ref, mobility, iterations)
        np.testing.assert_allclose(fast, expected, rtol=0.0, atol=1e-6)
        assert (np.isnan(fast) == np.isnan(expected)).all()
        assert enforce_bone_lengths(joints, ref).tobytes() == plain_enforce(joints, ref).tobytes()
        one = enforce_bone_lengths(joints[0], ref[0])
        assert one.tobytes() == plain_enforce(joints[0], ref[0]).tobytes()


def test_one_reference_or_mobility_for_many_skeletons_broadcasts() -> None:
    rng = np.random.default_rng(7)
    joints = rng.normal(size=(4, 25, 3)) * 0.3
    ref = rng.uniform(0.05, 0.5, size=24)
    mobility = rng.uniform(0.1, 1.0, size=25)
    fitted = project_bone_lengths(joints, ref, mobility)
    expected = plain_project(joints, np.broadcast_to(ref, (4, 24)), np.tile(mobility, (4, 1)), 3)
    np.testing.assert_allclose(fitted, expected, rtol=0.0, atol=1e-6)
    one = project_bone_lengths(joints[0], ref, mobility)  # (25, 3)
    assert one.shape == (25, 3)
    np.testing.assert_allclose(one, expected[0], rtol=0.0, atol=1e-6)


def test_the_projection_compiles_once_whatever_arrays_it_is_given() -> None:
    """Strided, read-only, one-skeleton inputs reuse the warm-up's compilation (none
    mid-stream)."""
    bone_fit.warm_up()
    if not hasattr(bone_fit.project_loop, "signatures"):
        pytest.skip("the loop is not compiled (NUMBA_DISABLE_JIT)")
    views = (np.random.default_rng(0).normal(size=(12, 25, 3)) * 0.3)[::2]
    views.flags.writeable = False
    lengths = np.full((len(views), 24), 0.3)[:, ::-1]
    project_bone_lengths(views, lengths, np.ones(25), iterations=2)
    project_bone_lengths(views[0], lengths[0])
    assert len(bone_fit.project_loop.signatures) == 1
