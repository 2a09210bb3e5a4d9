"""The damped-acceleration Kalman's compiled loops give the numpy path's bits.

Persons' filters stepped together (filters.filter_all) over noisy motion with joints that go
missing, come back and restart after a gap, at irregular step lengths, once with the compiled
loops (skelfuse.fusion.kernels_filter: the usual step whole, the correction of the others) and
once with numpy: every output and every state the same bits.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from skelfuse.fusion import kernels, kernels_filter
from skelfuse.fusion.filters import filter_all
from skelfuse.fusion.filters_ca import DampedAccelerationKalman


def _filters(count: int) -> list[DampedAccelerationKalman]:
    return [DampedAccelerationKalman(3.0, 0.03, 0.1, 0.006, jerk_per_speed=30.0)
            for _ in range(count)]  # fmt: skip


@pytest.mark.parametrize("seed", range(4))
def test_compiled_loops_step_the_filters_as_numpy_does(
    numba_kernels: None, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    whole: list[bool] = []  # per step with the kernels on: did the usual step's loop take it?
    step_all = kernels_filter.step_all

    def counted(*args: Any) -> Any:
        stepped = step_all(*args)
        whole.append(stepped is not None)
        return stepped

    monkeypatch.setattr(kernels_filter, "step_all", counted)
    rng = np.random.default_rng(seed)
    persons = int(rng.integers(1, 7))
    compiled, reference = _filters(persons), _filters(persons)
    t_s = 100.0
    joints = rng.normal(0.0, 1.0, (persons, 25, 3))
    for k in range(80):
        t_s += [1 / 30, 1 / 30, 1 / 30, 0.021, 0.7][k % 5 if k % 17 == 0 else 0]
        joints = joints + rng.normal(0.0, 0.02, joints.shape)
        sample = joints.copy()
        missing = 0.3 if k % 11 == 0 else 0.02 if k % 3 == 0 else 0.0  # some steps whole
        sample[rng.random((persons, 25)) < missing] = np.nan
        got = filter_all(list(compiled), sample, t_s)
        with kernels.forced("numpy"):
            assert not (kernels.enabled() and kernels_filter.warmed())
            want = filter_all(list(reference), sample, t_s)
        for g, w in zip(got, want, strict=True):
            assert g.tobytes() == w.tobytes()
    for a, b in zip(compiled, reference, strict=True):
        for sa, sb in zip(a._state(), b._state(), strict=True):
            assert sa.tobytes() == sb.tobytes()
    assert 15 < sum(whole) < len(whole)  # both: the usual steps whole, the others by numpy


@pytest.mark.parametrize("broken", ["z", "x", "t gap", "t same", "t other"])
def test_the_usual_steps_loop_gives_up_whenever_numpy_would_not_step_every_coordinate(
    numba_kernels: None, broken: str
) -> None:
    # Each of KalmanState._step's conditions, broken for one coordinate of an otherwise
    # usual step: the loop answers None (numpy's path takes it) instead of stepping.
    rng = np.random.default_rng(3)
    z, last_x = rng.normal(size=(2, 25, 3)), rng.normal(size=(2, 25, 3, 3))
    last_p = np.broadcast_to(np.eye(3), (2, 25, 3, 3, 3)).copy()
    last_t, t_s = np.full((2, 25, 3), 10.0), 10.0 + 1 / 30
    transition = DampedAccelerationKalman()._transition(np.array([1 / 30]))
    args = (transition, (3.0, 30.0, 0.03**2), 0.5, (0.006, 0.006**2 / 2))
    assert kernels_filter.step_all(z, last_x, last_p, last_t, t_s, *args) is not None
    where = (1, 20, 2)
    if broken == "z":
        z[where] = np.nan
    elif broken == "x":
        last_x[where][0] = np.nan
    else:
        last_t[where] = {"t gap": 9.0, "t same": t_s, "t other": 10.001}[broken]
    assert kernels_filter.step_all(z, last_x, last_p, last_t, t_s, *args) is None
