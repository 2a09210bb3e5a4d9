"""The damped-acceleration Kalman's step against the filter written with matrices, below.

Persons' filters stepped together (filters.filter_all) over noisy motion with joints that go
missing, come back and restart after a gap, at irregular step lengths: every output and state
within 1e-9 of KalmanState's rule with F x, F P Fᵀ + jerk²·Q and the gain as matrix products;
then the usual step's loop (one F for all) gives up whenever a coordinate would not step by
that F, and the step takes it with one F per coordinate.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import filters as filters_module
from skelfuse.fusion.filters import DampedAccelerationKalman, filter_all


def _filters(count: int) -> list[DampedAccelerationKalman]:
    return [DampedAccelerationKalman(3.0, 0.03, 0.1, 0.006, jerk_per_speed=30.0)
            for _ in range(count)]  # fmt: skip


def matrix_step(
    kalman: DampedAccelerationKalman,
    state: tuple[np.ndarray, np.ndarray, np.ndarray],
    z: np.ndarray,
    t_s: float,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """One sample, coordinate by coordinate, as KalmanState says: step, restart or keep."""
    last_x, last_p, last_t = (a.reshape(-1, *a.shape[z.ndim :]) for a in state)
    x, p, t = last_x.copy(), last_p.copy(), last_t.copy()
    out = np.full(z.size, np.nan)
    h_r = kalman.r
    for c, value in enumerate(z.reshape(-1)):
        if not np.isfinite(value):
            continue
        dt = t_s - last_t[c]
        if not np.isfinite(last_x[c, 0]) or dt > kalman.reset_gap_s:
            x[c], p[c] = [value, 0.0, 0.0], np.diag([h_r, 1.0, 100.0])
        elif dt > 0:
            f, q = (m[0] for m in kalman._transition(np.array([dt])))
            jerk = kalman.jerk_std + kalman.jerk_per_speed * abs(last_x[c, 1])
            x_p, p_p = f @ last_x[c], f @ last_p[c] @ f.T + jerk**2 * q
            gain = p_p[:, 0] / (p_p[0, 0] + h_r)
            x[c] = x_p + gain * (value - x_p[0])
            p[c] = p_p - np.outer(gain, p_p[0])
        t[c] = t_s
        lead = kalman.predict_s
        out[c] = x[c, 0] + lead * x[c, 1] + lead * lead / 2 * x[c, 2]
    shape = z.shape
    return out.reshape(shape), (x.reshape(*shape, 3), p.reshape(*shape, 3, 3), t.reshape(shape))


@pytest.mark.parametrize("seed", range(4))
def test_the_step_is_the_kalman_written_with_matrices(seed: int) -> None:
    rng = np.random.default_rng(seed)
    persons = int(rng.integers(1, 7))
    filters = _filters(persons)
    t_s = 100.0
    joints = rng.normal(0.0, 1.0, (persons, 25, 3))
    filter_all(list(filters), joints, t_s)
    for k in range(60):
        t_s += [1 / 30, 1 / 30, 1 / 30, 0.021, 0.7][k % 5 if k % 17 == 0 else 0]
        joints = joints + rng.normal(0.0, 0.02, joints.shape)
        sample = joints.copy()
        missing = 0.3 if k % 11 == 0 else 0.02 if k % 3 == 0 else 0.0  # some steps whole
        sample[rng.random((persons, 25)) < missing] = np.nan
        before = [f._state() for f in filters]
        got = filter_all(list(filters), sample, t_s)
        for person, kalman in enumerate(filters):
            want, state = matrix_step(kalman, before[person], sample[person], t_s)
            np.testing.assert_allclose(got[person], want, rtol=1e-9, atol=1e-12)
            for mine, theirs in zip(kalman._state(), state, strict=True):
                np.testing.assert_allclose(mine, theirs, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("broken", ["z", "x", "t gap", "t same", "t other"])
def test_the_usual_steps_loop_gives_up_whenever_a_coordinate_does_not_step_by_its_f(
    broken: str,
) -> None:
    # Each of KalmanState._step's conditions, broken for one coordinate of an otherwise usual
    # step: the loop with one F for all answers None, and the step takes it coordinate by
    # coordinate.
    rng = np.random.default_rng(3)
    z, last_x = rng.normal(size=(2, 25, 3)), rng.normal(size=(2, 25, 3, 3))
    last_p = np.broadcast_to(np.eye(3), (2, 25, 3, 3, 3)).copy()
    last_t, t_s = np.full((2, 25, 3), 10.0), 10.0 + 1 / 30
    kalman = DampedAccelerationKalman(3.0, 0.03, 0.1, 0.006, jerk_per_speed=30.0)
    one = kalman._kept_transition(np.array([1 / 30]))
    assert kalman._looped(z, last_x, last_p, last_t, t_s, one, usual=True) is not None
    where = (1, 20, 2)
    if broken == "z":
        z[where] = np.nan
    elif broken == "x":
        last_x[where][0] = np.nan
    else:
        last_t[where] = {"t gap": 9.0, "t same": t_s, "t other": 10.001}[broken]
    assert kalman._looped(z, last_x, last_p, last_t, t_s, one, usual=True) is None
    out, *state = kalman._step(z, last_x, last_p, last_t, t_s)
    want, want_state = matrix_step(kalman, (last_x, last_p, last_t), z, t_s)
    np.testing.assert_allclose(out, want, rtol=1e-9, atol=1e-12)
    for mine, theirs in zip(state, want_state, strict=True):
        np.testing.assert_allclose(mine, theirs, rtol=1e-9, atol=1e-12)


def test_the_warm_up_compiles_the_loop_for_every_step() -> None:
    """Stacked persons, a missing coordinate, one filter alone: no second compilation."""
    filters_module.warm_up()
    if not hasattr(filters_module.step_loop, "signatures"):
        pytest.skip("the loop is not compiled (NUMBA_DISABLE_JIT)")
    filters = _filters(3)
    joints = np.zeros((3, 25, 3))
    filter_all(list(filters), joints, 1.0)
    joints[1, 4] = np.nan
    filter_all(list(filters), joints[:, :, :][::1], 1.0 + 1 / 30)
    filters[0](joints[0], 1.1)
    assert len(filters_module.step_loop.signatures) == 1
