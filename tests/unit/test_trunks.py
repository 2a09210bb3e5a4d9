"""Association's trunk distances against the rule written below, pair by pair.

skelfuse.fusion.identity.trunk_distances on pairs with unknown coordinates, infinities, pairs
sharing zero, one, two or five joints, equal points and distances over many magnitudes, as
stacked pairs and broadcast views × tracks; sticky_distances against the tracks' predictions;
then the tracker keeps the persons of an episode apart and finds them again.
"""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.fusion import identity


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


def one_pair(a: np.ndarray, b: np.ndarray) -> float:
    """The rule: the mean distance over the joints both have, inf with fewer than two."""
    both = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    return float(np.linalg.norm(a[both] - b[both], axis=1).mean()) if both.sum() >= 2 else np.inf


@pytest.mark.parametrize("seed", range(40))
def test_trunk_distances_are_each_pairs_mean_distance(seed: int) -> None:
    a, b = _pairs(seed)
    got = identity.trunk_distances(a, b)
    want = [one_pair(a[m], b[m]) for m in range(len(a))]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
    assert np.isinf(got[0])  # one joint in common


def test_views_against_tracks_broadcast() -> None:
    a, b = _pairs(5)
    got = identity.trunk_distances(a[:, None], b[None, :])
    assert got.shape == (len(a), len(b))
    want = [[one_pair(x, y) for y in b] for x in a]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
    assert identity.trunk_distances(a[:1], b[:3]).shape == (3,)  # one against many


@pytest.mark.parametrize("seed", range(12))
def test_sticky_distances_are_those_to_the_tracks_predictions(seed: int) -> None:
    """Each view against its track's prediction (Track.predicted), with tracks last seen just
    now, long ago (clipped at 0.5 s) and later than the instant (a step of 0)."""
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
    got = identity.sticky_distances(
        joints,
        (
            np.array([t.joints for t in tracks]),
            np.array([t.velocity for t in tracks]),
            np.array([t.last_seen_s for t in tracks]),
        ),
        rows,
        1.0,
    )
    want = [
        one_pair(j[identity.TRUNK_JOINTS], tracks[r].predicted(1.0)[identity.TRUNK_JOINTS])
        for j, r in zip(joints, rows, strict=True)
    ]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
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


def test_the_tracker_keeps_the_episodes_persons() -> None:
    """Sticky membership, the Hungarian step after a re-numbering, a birth, a glitch past the
    sticky gate and a departure: each person keeps one id, one view per sensor."""
    from skelfuse.fusion.settings import FusionSettings

    tracker = identity.PersonTracker(FusionSettings())
    ids_of_person: dict[int, set[int]] = {}
    for k, views in enumerate(_episode()):
        clusters = tracker.associate(views, k / 30)
        fused = np.array([c[0].joints_world for c in clusters.values()])
        tracker.move_all(list(clusters), fused, k / 30)
        tracker.confirm(clusters, k / 30)
        for person_id, cluster in clusters.items():
            assert len({v.sensor_id for v in cluster}) == len(cluster)
            if k >= 30:  # the first person left: the others' tracking ids shifted
                continue
            # Each view's person in the episode: its tracking id's last digit.
            ids_of_person.setdefault(person_id, set()).update(v.tracking_id % 10 for v in cluster)
        if k in (5, 15, 22, 28):
            assert len(clusters) == (2 if k < 10 else 3) and all(
                len(c) == 3 for c in clusters.values()
            )
    assert all(len(people) == 1 for people in ids_of_person.values())  # never two persons mixed
