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


@pytest.mark.parametrize("seed", range(12))
def test_sticky_distances_are_those_of_the_trunks_and_predictions(
    numba_kernels: None, seed: int
) -> None:
    """Each view against its track's prediction: the bits of trunk_distances on _trunks and
    _predicted_trunks, with tracks last seen just now, long ago (clipped at 0.5 s) and later
    than the instant (a step of 0)."""
    rng = np.random.default_rng(seed)
    tracks = [
        identity.Track(
            k, rng.normal(0.0, 1.0, (25, 3)), float(rng.choice([0.99, 0.2, 1.3, 1.0])), 0.0,
            velocity=rng.normal(0.0, 1.5, 3),
        )
        for k in range(int(rng.integers(1, 7)))
    ]  # fmt: skip
    tracks[0].joints[identity.TRUNK_JOINTS[:2]] = np.nan  # a track missing trunk joints
    rows = rng.integers(0, len(tracks), int(rng.integers(1, 25)))
    joints = np.array([tracks[r].joints for r in rows]) + rng.normal(0.0, 0.1, (len(rows), 25, 3))
    joints[rng.random(joints.shape[:2]) < 0.1] = np.nan
    views = [identity.View("s", k, j, np.full(25, 2, np.uint8)) for k, j in enumerate(joints)]
    with kernels.forced("numpy"):
        want = identity.trunk_distances(
            identity._trunks(views), identity._predicted_trunks(tracks, 1.0)[rows]
        )
    got = kernels_trunks.sticky_distances(
        joints,
        (
            np.array([t.joints for t in tracks]),
            np.array([t.velocity for t in tracks]),
            np.array([t.last_seen_s for t in tracks]),
        ),
        rows,
        1.0,
        identity.TRUNK_JOINTS,
    )
    assert got.tobytes() == want.tobytes()
    assert np.isfinite(got).any()


def _episode() -> list[list[identity.View]]:
    """Steps of three sensors' views: persons walking, one born late, a sensor re-numbering
    its bodies (sticky membership lost: the Hungarian step), a view jumping past the sticky
    gate and a person leaving."""
    from tests.unit.test_fusion_and_tracking import standing

    rng = np.random.default_rng(3)
    steps: list[list[identity.View]] = []
    for k in range(40):
        people = [standing(-1.0 + 0.02 * k, 0.0), standing(1.0, 0.5 - 0.01 * k)]
        if k >= 10:
            people.append(standing(0.0, 2.0))  # born at step 10
        if k >= 30:
            people = people[1:]  # the first leaves
        views = []
        for s in range(3):
            base = 100 * s + (50 if s == 1 and k >= 20 else 0)  # sensor 1 re-numbers at 20
            for p, joints in enumerate(people):
                seen = joints + rng.normal(0.0, 0.01, joints.shape)
                if s == 2 and p == 0 and k == 25:
                    seen = seen + [3.0, 0.0, 0.0]  # a glitch past the sticky gate
                views.append(identity.View(f"s{s}", base + p, seen, np.full(25, 2, np.uint8)))
        steps.append(views)
    return steps


def test_the_tracker_places_views_alike_on_both_paths(numba_kernels: None) -> None:
    from skelfuse.fusion.settings import FusionSettings

    def run(mode: str) -> list[list[tuple[int, list[tuple[str, int]]]]]:
        tracker = identity.PersonTracker(FusionSettings())
        out = []
        with kernels.forced(mode):
            for k, views in enumerate(_episode()):
                clusters = tracker.associate(views, k / 30)
                fused = np.array([c[0].joints_world for c in clusters.values()])
                tracker.move_all(list(clusters), fused, k / 30)
                tracker.confirm(clusters, k / 30)
                out.append(
                    sorted(
                        (p, [(v.sensor_id, v.tracking_id) for v in c]) for p, c in clusters.items()
                    )
                )
        return out

    got, want = run("numba"), run("numpy")
    assert got == want
    assert len({p for step in got for p, _ in step}) >= 3  # births happened
