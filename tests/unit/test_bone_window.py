"""The online bone estimate's window (fusion/bone_window.py) against a plain deque of samples."""

from __future__ import annotations

import warnings
from collections import deque

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion.bone_window import BONE_MIRROR, SampleWindow, nanmedian_axis

FloatArray = npt.NDArray[np.float64]


def quiet_nanmedian(data: FloatArray, axis: int) -> FloatArray:
    """np.nanmedian without its all-NaN-slice warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result: FloatArray = np.nanmedian(data, axis=axis)
    return result


def plain_median(
    samples: deque[FloatArray], min_samples: int, symmetric: bool
) -> tuple[FloatArray, FloatArray]:
    """The estimate as it was computed before the ring: stack, pool with the mirror, median."""
    if not samples:
        return np.full(24, np.nan), np.zeros(24)
    data = np.stack(samples)
    sides = 1
    if symmetric:
        data = np.concatenate([data, data[:, BONE_MIRROR]], axis=0)
        sides = 2
    counts = np.isfinite(data).sum(axis=0) / sides
    median = quiet_nanmedian(data, 0)
    return np.where(counts >= min_samples, median, np.nan), counts


@pytest.mark.parametrize("symmetric", [True, False])
@pytest.mark.parametrize("window", [1, 7, 40])
def test_the_window_gives_the_median_of_the_last_samples(window: int, symmetric: bool) -> None:
    rng = np.random.default_rng(window)
    ring, plain = SampleWindow(window), deque[FloatArray](maxlen=window)
    for step in range(120):
        sample = rng.uniform(0.1, 0.5, 24).round(3)  # rounded: ties between the middle values
        sample[rng.random(24) < 0.3] = np.nan
        ring.append(sample)
        plain.append(sample)
        if step % 37 == 5:
            ring.mirror()
            swapped = [s[BONE_MIRROR] for s in plain]
            plain.clear()
            plain.extend(swapped)
        assert len(ring) == len(plain)
        for min_samples in (1, 3):
            got, counts = ring.median(min_samples, symmetric)
            expected, expected_counts = plain_median(plain, min_samples, symmetric)
            assert got.tobytes() == expected.tobytes()
            assert counts.tobytes() == expected_counts.tobytes()


def test_an_empty_window_knows_nothing() -> None:
    median, counts = SampleWindow(0).median(1, True)
    assert np.isnan(median).all()
    assert (counts == 0).all()


def test_nanmedian_axis_is_nanmedian() -> None:
    rng = np.random.default_rng(3)
    data = rng.normal(size=(4, 5, 6)).round(1)
    data[rng.random(data.shape) < 0.4] = np.nan
    data[0, :, 0] = np.nan  # an all-NaN slice
    for axis in range(3):
        np.testing.assert_array_equal(nanmedian_axis(data, axis), quiet_nanmedian(data, axis))


@pytest.mark.parametrize("seed", range(6))
def test_the_median_along_the_last_axis_is_the_median_along_any_axis(seed: int) -> None:
    from skelfuse.fusion.bone_window import nanmedian_last

    rng = np.random.default_rng(seed)
    data = rng.normal(size=(3, 2, 24, int(rng.integers(1, 9))))
    data[rng.random(data.shape) < 0.4] = np.nan
    data[0, 0, 0] = np.nan  # a row with nothing
    want = nanmedian_axis(np.moveaxis(data, -1, 1), axis=1)
    assert nanmedian_last(data).tobytes() == want.tobytes()
