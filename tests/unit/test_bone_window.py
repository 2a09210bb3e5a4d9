"""The online bone estimate's window (fusion/bones.py) against a plain deque of samples,
and its medians against np.nanmedian and a sort written below (the rule with infinities)."""

from __future__ import annotations

import warnings
from collections import deque

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion.bones import (
    BONE_MIRROR,
    SampleWindow,
    nanmedian_axis,
    nanmedian_last,
    window_medians,
)

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
    rng = np.random.default_rng(seed)
    data = rng.normal(size=(3, 2, 24, int(rng.integers(1, 9))))
    data[rng.random(data.shape) < 0.4] = np.nan
    data[0, 0, 0] = np.nan  # a row with nothing
    want = nanmedian_axis(np.moveaxis(data, -1, 1), axis=1)
    assert nanmedian_last(data).tobytes() == want.tobytes()


def _rows(seed: int) -> FloatArray:
    """Rows of one to 700 values with NaN, ties, zeros, infinities, a row of NaN only and a
    row of one finite value."""
    rng = np.random.default_rng(seed)
    n = int(rng.choice([1, 2, 3, 7, 60, 600, 700]))
    rows = rng.normal(0.3, 0.05, (int(rng.integers(1, 30)), n))
    if seed % 3 == 0:
        rows = np.round(rows, 2)  # many ties
    rows[rng.random(rows.shape) < rng.uniform(0.0, 0.6)] = np.nan
    rows[0] = np.nan  # no finite value
    if len(rows) > 1:
        rows[1] = np.nan
        rows[1, -1] = 0.25  # one
    if seed % 4 == 1:
        rows[rng.random(rows.shape) < 0.05] = np.inf
        rows[rng.random(rows.shape) < 0.05] = -np.inf
        rows[rng.random(rows.shape) < 0.05] = 0.0
    return rows


def sorted_median(row: FloatArray) -> float:
    """The rule with infinities: the count is of finite values, the middle two places are taken
    among the sorted values that are not NaN; NaN without a finite value."""
    values = np.sort(row[~np.isnan(row)])
    count = int(np.isfinite(values).sum())
    if count == 0:
        return float("nan")
    return float((values[(count - 1) // 2] + values[count // 2]) / 2.0)


@pytest.mark.parametrize("seed", range(40))
def test_the_row_medians_follow_nanmedians_rule(seed: int) -> None:
    rows = _rows(seed)
    got = nanmedian_last(rows)
    np.testing.assert_allclose(got, [sorted_median(r) for r in rows], rtol=0.0, atol=1e-9)
    if seed % 4 != 1:  # no infinities: numpy's own nanmedian
        np.testing.assert_allclose(got, quiet_nanmedian(rows, 1), rtol=0.0, atol=1e-9)
        assert np.isnan(got[0]) and (len(rows) == 1 or got[1] == 0.25)


def test_an_empty_axis_has_no_median() -> None:
    assert np.isnan(nanmedian_last(np.zeros((3, 0)))).all()
    assert nanmedian_axis(np.zeros((0, 4)), 0).shape == (4,)


def test_the_window_medians_read_one_or_two_rows_per_output() -> None:
    window = np.array([[0.1, 0.2, 0.9, np.nan], [0.3, np.nan, np.nan, 5.0], [0.5, 0.5, 0.5, 0.5]])
    first = np.array([0, 0, 2], dtype=np.intp)
    second = np.array([1, -1, -1], dtype=np.intp)
    medians, counts = window_medians(window, 3, first, second, 2)
    # Row 0 with row 1 over 3 columns: 0.1, 0.2, 0.9, 0.3 (4 values from 2 rows: count 2).
    np.testing.assert_allclose(counts, [2.0, 3.0, 3.0], rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(medians, [0.25, 0.2, 0.5], rtol=0.0, atol=1e-12)
    medians, _ = window_medians(window, 3, first, second, 3)
    assert np.isnan(medians[0]) and medians[1] == 0.2  # below min_samples: NaN
