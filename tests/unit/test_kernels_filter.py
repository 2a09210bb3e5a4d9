"""The damped-acceleration Kalman's compiled correction gives the numpy path's bits.

Persons' filters stepped together (filters.filter_all) over noisy motion with joints that go
missing, come back and restart after a gap, at irregular step lengths, once with the compiled
correction (skelfuse.fusion.kernels_filter) and once with numpy: every output and every state
the same bits.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import kernels, kernels_filter
from skelfuse.fusion.filters import filter_all
from skelfuse.fusion.filters_ca import DampedAccelerationKalman


def _filters(count: int) -> list[DampedAccelerationKalman]:
    return [DampedAccelerationKalman(3.0, 0.03, 0.1, 0.006, jerk_per_speed=30.0)
            for _ in range(count)]  # fmt: skip


@pytest.mark.parametrize("seed", range(4))
def test_compiled_correction_steps_the_filters_as_numpy_does(
    numba_kernels: None, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    persons = int(rng.integers(1, 7))
    compiled, reference = _filters(persons), _filters(persons)
    t_s = 100.0
    joints = rng.normal(0.0, 1.0, (persons, 25, 3))
    for k in range(80):
        t_s += [1 / 30, 1 / 30, 1 / 30, 0.021, 0.7][k % 5 if k % 17 == 0 else 0]
        joints = joints + rng.normal(0.0, 0.02, joints.shape)
        sample = joints.copy()
        sample[rng.random((persons, 25)) < (0.3 if k % 11 == 0 else 0.02)] = np.nan
        got = filter_all(list(compiled), sample, t_s)
        with kernels.forced("numpy"):
            assert not (kernels.enabled() and kernels_filter.warmed())
            want = filter_all(list(reference), sample, t_s)
        for g, w in zip(got, want, strict=True):
            assert g.tobytes() == w.tobytes()
    for a, b in zip(compiled, reference, strict=True):
        for sa, sb in zip(a._state(), b._state(), strict=True):
            assert sa.tobytes() == sb.tobytes()
