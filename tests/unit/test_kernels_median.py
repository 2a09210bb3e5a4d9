"""The bone window's compiled row medians give the numpy path's bits.

skelfuse.fusion.kernels_median.row_medians against bone_window.nanmedian_last's numpy code on
rows of one to 700 values with NaN, ties, zeros, infinities, a row of NaN only and a row of
one finite value; then two SampleWindows fed the same observations through both paths give
the same estimates and counts; then the window kernel (``window_medians``, the whole of
``SampleWindow.median`` in one call) against numpy's path on windows of every shape.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import bone_window, kernels, kernels_median


def _rows(seed: int) -> np.ndarray:
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


@pytest.mark.parametrize("seed", range(40))
def test_compiled_row_medians_are_the_numpy_medians(numba_kernels: None, seed: int) -> None:
    rows = _rows(seed)
    with kernels.forced("numpy"):
        want = bone_window.nanmedian_last(rows)
    got = kernels_median.row_medians(rows)
    assert got.tobytes() == want.tobytes()
    assert bone_window.nanmedian_last(rows).tobytes() == want.tobytes()  # the kernel ran
    finite = np.where(np.isfinite(rows), rows, np.nan)
    if seed % 4 != 1:  # no infinities: numpy's own nanmedian is the rule
        with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
            np.testing.assert_array_equal(got, np.nanmedian(finite, axis=1))


def test_both_paths_give_the_same_window_estimates(numba_kernels: None) -> None:
    rng = np.random.default_rng(7)
    windows = {path: bone_window.SampleWindow(300) for path in ("numba", "numpy")}
    for step in range(700):
        lengths = rng.normal(0.3, 0.02, 24)
        lengths[rng.random(24) < 0.2] = np.nan
        for window in windows.values():
            window.append(lengths)
        if step % 10 == 0:
            got = {}
            for path, window in windows.items():
                with kernels.forced(path):
                    got[path] = window.median(10, symmetric=step % 20 == 0)
            assert got["numba"][0].tobytes() == got["numpy"][0].tobytes()
            assert got["numba"][1].tobytes() == got["numpy"][1].tobytes()


@pytest.mark.parametrize("seed", range(30))
def test_the_window_kernel_gives_the_numpy_window_medians(
    numba_kernels: None, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Windows of 1 to 40 observations, part full or wrapped, mirrored or not, with ties, NaN,
    # infinities; symmetric or not, any min_samples: the window kernel against numpy's path.
    rng = np.random.default_rng(seed)
    window = bone_window.SampleWindow(int(rng.integers(1, 40)))
    for _ in range(int(rng.integers(1, 60))):
        lengths = rng.choice([0.3, 0.31, 0.32, 0.5], 24)
        if seed % 2:
            lengths = lengths + rng.normal(0.0, 0.01, 24)
        lengths[rng.random(24) < rng.random()] = np.nan
        if seed % 5 == 0:
            lengths[rng.integers(24)] = np.inf
        window.append(lengths)
    if seed % 3 == 0:
        window.mirror()
    calls: list[int] = []
    compiled = kernels_median.window_medians
    monkeypatch.setattr(
        kernels_median, "window_medians", lambda *a: calls.append(1) or compiled(*a)
    )
    for symmetric in (True, False):
        min_samples = int(rng.integers(0, 8))
        got = window.median(min_samples, symmetric)
        with kernels.forced("numpy"):
            want = window.median(min_samples, symmetric)
        assert got[0].tobytes() == want[0].tobytes()
        assert got[1].tobytes() == want[1].tobytes()
    assert len(calls) == 2  # the kernel ran, both times


def test_the_window_kernel_reads_one_or_two_rows_per_output() -> None:
    window = np.array([[0.1, 0.2, 0.9, np.nan], [0.3, np.nan, np.nan, 5.0], [0.5, 0.5, 0.5, 0.5]])
    first = np.array([0, 0, 2], dtype=np.intp)
    second = np.array([1, -1, -1], dtype=np.intp)
    medians, counts = kernels_median.window_medians(window, 3, first, second, 2)
    # Row 0 with row 1 over 3 columns: 0.1, 0.2, 0.9, 0.3 (4 values from 2 rows: count 2).
    np.testing.assert_array_equal(counts, [2.0, 3.0, 3.0])
    np.testing.assert_array_equal(medians, [(0.2 + 0.3) / 2, 0.2, 0.5])
    medians, _ = kernels_median.window_medians(window, 3, first, second, 3)
    assert np.isnan(medians[0]) and medians[1] == 0.2  # below min_samples: NaN
