"""The bone window's compiled row medians give the numpy path's bits.

skelfuse.fusion.kernels_median.row_medians against bone_window.nanmedian_last's numpy code on
rows of one to 700 values with NaN, ties, zeros, infinities, a row of NaN only and a row of
one finite value; then two SampleWindows fed the same observations through both paths give
the same estimates and counts.
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
