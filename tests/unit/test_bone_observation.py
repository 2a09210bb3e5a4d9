"""The online bone observation: per person and bone, the median length its views show.

skelfuse.fusion.bones.bone_medians against np.nanmedian over each person's views, written
below, on persons with one to nine views, unknown joints, bones of length zero, untracked ends,
facing cosines that are unknown, behind or on the boundary, and a person without views; then
observe_bone_lengths feeds the estimates of the persons whose lengths are not set.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skelfuse.fusion import bones
from skelfuse.protocol.skeleton import BONES

PARENT = np.array([p for p, _ in BONES])
CHILD = np.array([c for _, c in BONES])


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


def reference_medians(
    joints: np.ndarray, states: np.ndarray, cosines: np.ndarray, person_of: np.ndarray, persons: int
) -> np.ndarray:
    """(persons, 2, 24): np.nanmedian of each person's lengths, good views then any view."""
    tracked = (states[:, PARENT] == 2) & (states[:, CHILD] == 2)
    lengths = np.linalg.norm(joints[:, CHILD] - joints[:, PARENT], axis=-1)
    lengths = np.where(tracked, lengths, np.nan)
    good = np.isfinite(cosines) & (cosines >= bones.GOOD_VIEW_COS)
    out = np.full((persons, 2, 24), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: NaN
        for p in range(persons):
            for kind, chosen in enumerate((good & (person_of == p), person_of == p)):
                if chosen.any():
                    out[p, kind] = np.nanmedian(lengths[chosen], axis=0)
    return out


@pytest.mark.parametrize("seed", range(30))
def test_the_medians_are_each_persons_median_lengths(seed: int) -> None:
    joints, states, cosines, person_of, _, persons, _ = _step(seed)
    got = bones.bone_medians(joints, states, cosines, person_of, int(persons))
    want = reference_medians(joints, states, cosines, person_of, int(persons))
    np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-9)  # NaN where NaN
    assert np.isfinite(got).any() and np.isnan(got).any()


def test_observation_feeds_the_estimates_not_set_by_hand() -> None:
    models = [bones.BoneModel(40, 1, symmetric=False) for _ in range(7)]
    models[1].set_lengths = np.full(24, 0.25)
    joints, states, cosines, person_of, slot_of, persons, widest = _step(3)
    bones.observe_bone_lengths(
        models[: int(persons)], joints, states, cosines, person_of, slot_of, int(widest)
    )
    want = reference_medians(joints, states, cosines, person_of, int(persons))
    for p in range(int(persons)):
        model = models[p]
        if p == 1:
            np.testing.assert_array_equal(model.estimate, np.full(24, np.nan))
            continue
        # One step: a bone good views show takes their median, the others any view's.
        good, spare = want[p]
        expected = np.where(np.isfinite(good), good, spare)
        np.testing.assert_allclose(model.estimate, expected, rtol=0.0, atol=1e-9)
