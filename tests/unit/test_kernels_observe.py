"""The bone observation's compiled per-view medians give the numpy path's bits.

skelfuse.fusion.kernels_observe.bone_medians against skelfuse.fusion.bones.per_bone_medians on
persons with one to nine views, unknown joints, bones of length zero, untracked ends, facing
cosines that are unknown, behind or on the boundary, and a person without views; then
observe_bone_lengths fed the same steps through both paths ends with the same estimates.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import bones, kernels, kernels_observe


def _step(seed: int) -> tuple[np.ndarray, ...]:
    """One step's views of P persons: joints, states, cosines, person_of, slot_of, P, widest."""
    rng = np.random.default_rng(seed)
    counts = [int(c) for c in rng.integers(1, 10, int(rng.integers(1, 7)))]
    counts.insert(int(rng.integers(0, len(counts) + 1)), 0)  # a person no view shows
    n = sum(counts)
    joints = rng.normal(0.0, 0.4, (n, 25, 3)) + [0.0, 1.0, 0.0]
    joints[rng.random((n, 25)) < 0.1] = np.nan
    joints[:, 3] = joints[:, 2]  # a bone of length zero
    states = rng.integers(0, 3, (n, 25)).astype(np.uint8)
    states[rng.random(n) < 0.3] = 2  # some views with every joint tracked
    cosines = rng.uniform(-1.0, 1.0, n)
    cosines[rng.random(n) < 0.1] = np.nan
    cosines[rng.random(n) < 0.1] = bones.GOOD_VIEW_COS  # on the boundary
    person_of = np.repeat(np.arange(len(counts)), counts)
    starts = np.cumsum([0, *counts])
    slot_of = np.arange(n) - starts[person_of]
    return joints, states, cosines, person_of, slot_of, np.array(len(counts)), np.array(max(counts))


@pytest.mark.parametrize("seed", range(30))
def test_compiled_medians_are_the_numpy_medians(numba_kernels: None, seed: int) -> None:
    joints, states, cosines, person_of, slot_of, persons, widest = _step(seed)
    want = bones.per_bone_medians(
        joints, states, cosines, person_of, slot_of, int(persons), int(widest)
    )
    got = kernels_observe.bone_medians(
        joints, states, cosines, person_of, int(persons), bones._BONE_ENDS, 2, 0.5
    )
    assert got.tobytes() == want.tobytes()


def test_both_paths_estimate_the_same_lengths(numba_kernels: None) -> None:
    compiled, reference = ([bones.BoneModel(40, 5) for _ in range(7)] for _ in range(2))
    for seed in range(60):
        joints, states, cosines, person_of, slot_of, persons, widest = _step(seed % 7)
        joints = joints + np.random.default_rng(seed).normal(0.0, 0.01, joints.shape)
        models = (compiled, reference)
        for chosen, path in zip(models, ("numba", "numpy"), strict=True):
            with kernels.forced(path):
                assert (kernels.enabled() and kernels_observe.warmed()) == (path == "numba")
                bones.observe_bone_lengths(
                    chosen[: int(persons)], joints, states, cosines, person_of, slot_of,
                    int(widest),
                )  # fmt: skip
    for a, b in zip(compiled, reference, strict=True):
        assert a.estimate.tobytes() == b.estimate.tobytes()
    assert np.isfinite(compiled[0].estimate).any()
