"""Temporal filters: One Euro against a scalar reference, Kalman, NaN handling, latency."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skelfuse.fusion.filters import ConstantVelocityKalman, OneEuroFilter, PassThrough, make_filter


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


@pytest.mark.parametrize("kind", ["one_euro", "kalman"])
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


@pytest.mark.parametrize("kind", ["one_euro", "kalman", "none"])
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


def test_filter_all_matches_separate_calls() -> None:
    from skelfuse.fusion.filters import filter_all

    rng = np.random.default_rng(3)
    together = [OneEuroFilter(1.5, 10.0), OneEuroFilter(1.5, 10.0), PassThrough()]
    apart = [OneEuroFilter(1.5, 10.0), OneEuroFilter(1.5, 10.0), PassThrough()]
    for k in range(20):
        sample = rng.normal(size=(3, 25, 3))
        sample[rng.random((3, 25, 3)) < 0.1] = np.nan
        got = filter_all(together, sample, k / 30)  # type: ignore[arg-type]
        for f, x, y in zip(apart, sample, got, strict=True):
            np.testing.assert_array_equal(f(x, k / 30), y)
