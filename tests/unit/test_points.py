"""fusion.points: the faster whole-point finiteness check gives numpy's booleans."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion.points import finite_points


@pytest.mark.parametrize("shape", [(3,), (25, 3), (4, 6, 25, 3), (0, 3)])
def test_finite_points_is_isfinite_all_over_the_last_axis(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(len(shape))
    points = rng.normal(size=shape)
    bad = rng.random(shape) < 0.2
    points[bad] = rng.choice([np.nan, np.inf, -np.inf], size=int(bad.sum()))
    got = finite_points(points)
    want = np.isfinite(points).all(axis=-1)
    assert got.shape == want.shape and got.dtype == np.bool_
    assert np.array_equal(got, want)
    assert np.array_equal(finite_points(points.astype(np.float32)), want)
