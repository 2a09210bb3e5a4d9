"""Association's compiled trunk distances give the numpy path's bits.

skelfuse.fusion.kernels_trunks.trunk_distances against identity.trunk_distances' numpy code on
pairs with unknown coordinates, infinities, pairs sharing zero, one, two or five joints, equal
points and distances over many magnitudes; then the tracker, fed the same views through both
paths, keeps the same persons.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import identity, kernels, kernels_trunks


def _pairs(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 60))
    a = rng.normal(0.0, 1.0, (m, 5, 3)) * 10.0 ** rng.uniform(-4, 2, (m, 1, 1))
    b = a + rng.normal(0.0, 0.3, (m, 5, 3)) * 10.0 ** rng.uniform(-6, 1, (m, 5, 1))
    a[rng.random((m, 5, 3)) < 0.05] = np.nan
    b[rng.random((m, 5, 3)) < 0.05] = np.nan
    if seed % 3 == 0:
        a[rng.random((m, 5, 3)) < 0.03] = np.inf
    a[0, :4] = np.nan  # one joint in common
    if m > 1:
        b[1] = a[1]  # equal points
    if m > 2:
        b[2, :] = np.nan  # none in common
    return a, b


@pytest.mark.parametrize("seed", range(40))
def test_compiled_trunk_distances_are_the_numpy_distances(numba_kernels: None, seed: int) -> None:
    a, b = _pairs(seed)
    with kernels.forced("numpy"), np.errstate(invalid="ignore"):  # inf - inf: NaN, unused
        want = identity.trunk_distances(a, b)
    got = kernels_trunks.trunk_distances(a, b)
    assert got.tobytes() == want.tobytes()
    assert identity.trunk_distances(a, b).tobytes() == want.tobytes()  # the kernel ran
    for m in range(len(a)):  # the rule, pair by pair: the joints both have, fewer than 2: inf
        both = np.isfinite(a[m]).all(axis=1) & np.isfinite(b[m]).all(axis=1)
        one = np.linalg.norm(a[m, both] - b[m, both], axis=1).mean() if both.sum() >= 2 else np.inf
        np.testing.assert_allclose(got[m], one, rtol=1e-12)


def test_broadcast_shapes_still_take_numpy(numba_kernels: None) -> None:
    a, b = _pairs(5)
    got = identity.trunk_distances(a[:, None], b[None, :])
    assert got.shape == (len(a), len(b))
    with kernels.forced("numpy"):
        want = identity.trunk_distances(a[:, None], b[None, :])
    assert got.tobytes() == want.tobytes()
