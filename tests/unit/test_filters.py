"""Temporal filters: One Euro against a scalar reference, Kalman, NaN handling, latency."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from bench.accuracy.lag import SHIFTS_S, best_shift, shift_errors
from skelfuse.fusion.filters import (
    ConstantVelocityKalman,
    DampedAccelerationKalman,
    JointFilter,
    OneEuroFilter,
    PassThrough,
    make_filter,
)


class ScalarOneEuro:
    """The authors' reference algorithm (Casiez et al. 2012; OneEuroFilter 0.2.1), scalar."""

    def __init__(self, min_cutoff: float, beta: float, d_cutoff: float) -> None:
        self.min_cutoff, self.beta, self.d_cutoff = min_cutoff, beta, d_cutoff
        self.x: float | None = None
        self.dx = 0.0
        self.t = 0.0

    @staticmethod
    def alpha(cutoff: float, te: float) -> float:
        tau = 1.0 / (2 * math.pi * cutoff)
        return 1.0 / (1.0 + tau / te)

    def __call__(self, x: float, t: float) -> float:
        if self.x is None:
            self.x, self.t = x, t
            return x
        te = t - self.t
        dx = (x - self.x) / te
        a_d = self.alpha(self.d_cutoff, te)
        self.dx = a_d * dx + (1 - a_d) * self.dx
        cutoff = self.min_cutoff + self.beta * abs(self.dx)
        a = self.alpha(cutoff, te)
        self.x = a * x + (1 - a) * self.x
        self.t = t
        return self.x


def test_one_euro_matches_the_scalar_reference() -> None:
    rng = np.random.default_rng(1)
    signal = np.cumsum(rng.normal(0, 0.02, size=(90, 25, 3)), axis=0)
    times = np.cumsum(rng.uniform(0.025, 0.04, size=90))
    vector = OneEuroFilter(1.0, 4.0, 1.0)
    scalar = ScalarOneEuro(1.0, 4.0, 1.0)
    for x, t in zip(signal, times, strict=True):
        out = vector(x, float(t))
        expected = scalar(float(x[7, 1]), float(t))
        assert out[7, 1] == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize("kind", ["one_euro", "kalman", "kalman_ca"])
def test_filters_reduce_noise_on_a_still_joint(kind: str) -> None:
    rng = np.random.default_rng(0)
    f = make_filter(kind)
    values = [f(np.array([rng.normal(0, 0.01)]), n / 30)[0] for n in range(300)]
    assert np.std(values[50:]) < 0.7 * 0.01


def test_kalman_follows_a_ramp_without_lag_and_prediction_leads() -> None:
    plain, ahead = ConstantVelocityKalman(8.0, 0.03), ConstantVelocityKalman(8.0, 0.03, 0.1)
    for n in range(150):
        t = n / 30
        y = plain(np.array([t]), t)[0]
        y_ahead = ahead(np.array([t]), t)[0]
    assert y == pytest.approx(t, abs=0.005)
    assert y_ahead == pytest.approx(t + 0.1, abs=0.01)


@pytest.mark.parametrize("kind", ["one_euro", "kalman", "kalman_ca", "none"])
def test_missing_joint_stays_missing_and_restarts_after_a_gap(kind: str) -> None:
    f = make_filter(kind)
    x = np.zeros((25, 3))
    f(x, 0.0)
    gap = x.copy()
    gap[3] = np.nan
    out = f(gap, 1 / 30)
    assert np.isnan(out[3]).all() and np.isfinite(out[4]).all()
    back = np.zeros((25, 3))
    back[3] = 1.0
    out = f(back, 2.0)  # joint 3 back after 2 s far away: restarts there, no slow glide
    np.testing.assert_allclose(out[3], 1.0)


def test_unknown_filter_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown filter"):
        make_filter("butterworth")
    assert isinstance(make_filter("none"), PassThrough)


def _mixed() -> list[JointFilter]:
    return [OneEuroFilter(1.5, 10.0), OneEuroFilter(1.5, 10.0), PassThrough(),
            ConstantVelocityKalman(6.0, 0.03, 0.01), ConstantVelocityKalman(6.0, 0.03, 0.01),
            ConstantVelocityKalman(8.0, 0.03),
            DampedAccelerationKalman(3.0, 0.03, 0.3, 0.008, 0.5, 20.0),
            DampedAccelerationKalman(3.0, 0.03, 0.3, 0.008, 0.5, 20.0)]  # fmt: skip


def test_filter_all_matches_separate_calls() -> None:
    """One Euro and both Kalman filters stepped together give exactly what separate calls give."""
    from skelfuse.fusion.filters import filter_all

    rng = np.random.default_rng(3)
    together, apart = _mixed(), _mixed()
    for k in range(20):
        sample = rng.normal(size=(8, 25, 3))
        sample[rng.random((8, 25, 3)) < 0.1] = np.nan
        got = filter_all(together, sample, k / 30)
        for f, x, y in zip(apart, sample, got, strict=True):
            np.testing.assert_array_equal(f(x, k / 30), y)


def test_filter_all_with_stacks_matches_separate_calls_as_groups_change() -> None:
    """With the caller's ``stacks`` (the last call's stacked states stepped again), the same
    bits as separate calls while the groups change under it: the filters reordered, one
    restarted, one stepped on its own in between, one left out of a call."""
    from skelfuse.fusion.filters import Stacks, filter_all

    rng = np.random.default_rng(4)
    together, apart = _mixed(), _mixed()
    stacks: Stacks = {}
    order = list(range(8))
    for k in range(30):
        t_s = k / 30
        if k == 8:
            order = order[::-1]  # the same filters, another order: rows must not be reused
        if k == 14:  # a restart: new state arrays for filter 1
            together[1], apart[1] = OneEuroFilter(1.5, 10.0), OneEuroFilter(1.5, 10.0)
        if k == 20:  # filter 7 stepped alone: its rows are no longer the stack's
            lone = rng.normal(size=(25, 3))
            np.testing.assert_array_equal(together[7](lone, t_s - 0.01), apart[7](lone, t_s - 0.01))
        chosen = [i for i in order if not (k == 24 and i == 4)]
        sample = rng.normal(size=(len(chosen), 25, 3))
        sample[rng.random(sample.shape) < 0.1] = np.nan
        got = filter_all([together[i] for i in chosen], sample, t_s, stacks)
        for i, x, y in zip(chosen, sample, got, strict=True):
            np.testing.assert_array_equal(apart[i](x, t_s), y)
    assert stacks  # the stacks were kept and used


@pytest.mark.parametrize("kind", ["kalman_ca", "kalman", "one_euro"])
def test_filter_all_one_group_with_stacks_matches_separate_calls(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The usual step (one group, the last call's filters) takes the short path, which steps
    the kept stacks as they are: the same bits as separate calls, and the long path whenever
    the filters are reordered, restarted, stepped alone or one is left out."""
    from skelfuse.fusion import filters

    short: list[int] = []
    same_group = filters._same_group

    def counted(*args: Any) -> bool:
        same = same_group(*args)
        if same:
            short.append(len(args[0]))
        return same

    monkeypatch.setattr(filters, "_same_group", counted)
    rng = np.random.default_rng(6)
    together = [filters.make_filter(kind) for _ in range(6)]
    apart = [filters.make_filter(kind) for _ in range(6)]
    stacks: filters.Stacks = {}
    order = list(range(6))
    changed = {8, 14, 15, 20, 24, 25}  # a restarted filter starts alone, then joins; one left
    # out and back: both calls stack afresh
    for k in range(30):
        t_s = k / 30
        if k == 8:
            order = order[::-1]
        if k == 14:
            together[1], apart[1] = filters.make_filter(kind), filters.make_filter(kind)
        if k == 20:
            lone = rng.normal(size=(25, 3))
            np.testing.assert_array_equal(together[5](lone, t_s - 0.01), apart[5](lone, t_s - 0.01))
        chosen = [i for i in order if not (k == 24 and i == 4)]
        sample = rng.normal(size=(len(chosen), 25, 3))
        before = len(short)
        got = filters.filter_all([together[i] for i in chosen], sample, t_s, stacks)
        for i, x, y in zip(chosen, sample, got, strict=True):
            np.testing.assert_array_equal(apart[i](x, t_s), y)
        if k >= 2:  # started, and stacked once
            assert (len(short) > before) == (k not in changed), k
    assert len(short) == 28 - len(changed)


def test_kalman_with_lead_leads_a_ramp_by_its_horizon_and_smooths_a_still_joint() -> None:
    """The recommended lead-compensated Kalman: on a constant-velocity ramp its output is
    ``predict_s`` ahead (no lag of its own); on a still joint it removes a third of the noise."""
    ramp = ConstantVelocityKalman(5.0, 0.03, 0.012)
    for n in range(150):
        y = ramp(np.full((25, 3), n / 30), n / 30)
    np.testing.assert_allclose(y, 149 / 30 + 0.012, atol=0.001)
    rng = np.random.default_rng(5)
    still = ConstantVelocityKalman(5.0, 0.03, 0.012)
    noise = rng.normal(0, 0.01, size=(300, 25, 3))
    values = np.stack([still(x, n / 30) for n, x in enumerate(noise)])
    assert np.std(values[50:]) < 0.75 * 0.01


def _sine(t: float) -> np.ndarray:
    return np.array([[np.sin(2 * np.pi * 0.7 * t), 0.3 * np.cos(2 * np.pi * 1.3 * t), 0.0]])


@pytest.mark.parametrize("shift_s", [0.0, 0.017, -0.009, 0.0333])
def test_lag_measure_recovers_a_known_shift(shift_s: float) -> None:
    """A trajectory that is the truth delayed by ``shift_s`` (plus a constant offset and noise,
    which are not lag) is measured to lag by ``shift_s`` to within a millisecond."""
    rng = np.random.default_rng(2)
    times = np.arange(0, 6, 1 / 30)
    fused = np.stack([_sine(t - shift_s) for t in times]) + 0.05
    fused += rng.normal(0, 0.002, size=fused.shape)
    fused[10:20] = np.nan
    errors = shift_errors(times, fused, _sine)
    assert best_shift(errors) == pytest.approx(shift_s, abs=0.001)
    assert len(errors) == len(SHIFTS_S)


def test_damped_acceleration_kalman_follows_a_parabola_and_its_lead_leads() -> None:
    """Constant acceleration: no lag once settled (a constant-velocity model lags behind it),
    and the lead extrapolates by its horizon; the acceleration decays once the joint stops."""
    plain = DampedAccelerationKalman(60.0, 0.03, accel_tau_s=10.0)
    ahead = DampedAccelerationKalman(60.0, 0.03, accel_tau_s=10.0, predict_s=0.05)
    cv = ConstantVelocityKalman(8.0, 0.03)
    for n in range(90):
        t = n / 30
        x = np.array([0.5 * t * t])  # 1 m/s²
        y, y_ahead, y_cv = plain(x, t)[0], ahead(x, t)[0], cv(x, t)[0]
    assert y == pytest.approx(x[0], abs=0.002)
    assert y_ahead == pytest.approx(0.5 * (t + 0.05) ** 2, abs=0.003)
    assert x[0] - y_cv > 3 * abs(x[0] - y)
    damped = DampedAccelerationKalman(60.0, 0.03, accel_tau_s=0.2)
    for n in range(60):
        damped(np.array([0.5 * (n / 30) ** 2]), n / 30)
    for n in range(60, 120):
        damped(np.array([0.5 * 4.0]), n / 30)  # stopped at 2 m
    assert damped._state()[0][0, 2] == pytest.approx(0.0, abs=0.05)


def test_speed_raises_the_damped_acceleration_kalman_gain() -> None:
    """With a jerk per unit of speed, a moving joint is followed more closely than with the
    still joint's jerk alone, and a still one is smoothed as much."""
    still, adaptive = (
        DampedAccelerationKalman(3.0),
        DampedAccelerationKalman(3.0, jerk_per_speed=40.0),
    )
    for n in range(60):
        t = n / 30
        x = np.array([np.sin(2 * math.pi * t)])
        lag_still, lag_adaptive = x[0] - still(x, t)[0], x[0] - adaptive(x, t)[0]
    assert abs(lag_adaptive) < 0.7 * abs(lag_still)
