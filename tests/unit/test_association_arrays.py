"""Association on stacked arrays: the distances, predictions and moves of the pair-by-pair rule.

:class:`~skelfuse.fusion.identity.PersonTracker` computes its cost matrices, birth and merge
distances for many pairs at once (:func:`~skelfuse.fusion.identity.trunk_distances` broadcast
over views × tracks): every distance must be the one
:func:`~skelfuse.fusion.identity.trunk_distance` gives for the pair, and moving persons together
must give each its own motion (the move as written for one person, below).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.fusion.identity import (
    TRUNK_JOINTS,
    PersonTracker,
    Track,
    _predicted_trunks,
    trunk_distance,
    trunk_distances,
)
from skelfuse.fusion.settings import FusionSettings
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import JOINT_COUNT


def skeletons(rng: np.random.Generator, count: int) -> npt.NDArray[np.float64]:
    joints = rng.normal(0.0, 1.0, (count, JOINT_COUNT, 3))
    joints[rng.random((count, JOINT_COUNT)) < 0.3] = np.nan  # some trunks with < 2 in common
    return joints


@pytest.mark.parametrize("seed", range(10))
def test_every_pair_at_once_gives_the_distance_of_each_pair(seed: int) -> None:
    rng = np.random.default_rng(seed)
    views, tracks = skeletons(rng, 7), skeletons(rng, 5)
    cost = trunk_distances(views[:, None, TRUNK_JOINTS], tracks[None, :, TRUNK_JOINTS])
    want = np.array([[trunk_distance(v, t) for t in tracks] for v in views])
    assert cost.shape == (7, 5)
    np.testing.assert_allclose(cost, want, rtol=1e-12, atol=0.0)
    assert np.isinf(want).any() and np.isfinite(want).any()  # both cases were exercised


def test_predictions_stacked_are_each_tracks_prediction() -> None:
    rng = np.random.default_rng(1)
    tracks = [
        Track(k + 1, joints, last_seen_s=10.0 - 0.2 * k, born_s=0.0, velocity=rng.normal(0, 1, 3))
        for k, joints in enumerate(skeletons(rng, 4))
    ]
    got = _predicted_trunks(tracks, 10.3)
    want = np.stack([t.predicted(10.3)[TRUNK_JOINTS] for t in tracks])
    assert got.tobytes() == want.tobytes()
    assert _predicted_trunks([], 1.0).shape == (0, len(TRUNK_JOINTS), 3)


def view(sensor_id: str, tracking_id: int, joints: npt.NDArray[np.float64]) -> View:
    return View(sensor_id, tracking_id, joints, np.full(JOINT_COUNT, 2, np.uint8))


def test_births_and_assignment_still_group_views_into_persons() -> None:
    rng = np.random.default_rng(4)
    people = [rng.normal(0.0, 0.2, (JOINT_COUNT, 3)) + [x, 1.0, 0.0] for x in (-2.0, 0.0, 2.0)]
    tracker = PersonTracker(FusionSettings())
    # Sensor a sees everyone, b two of them: births group them across sensors.
    first = [view("a", k, p + 0.01) for k, p in enumerate(people)]
    first += [view("b", 10 + k, p - 0.01) for k, p in enumerate(people[:2])]
    clusters = tracker.associate(first, 1.0)
    assert sorted(sorted((v.sensor_id, v.tracking_id) for v in c) for c in clusters.values()) == [
        [("a", 0), ("b", 10)],
        [("a", 1), ("b", 11)],
        [("a", 2)],
    ]
    tracker.confirm(clusters, 1.0)
    # New tracking ids everywhere: the Hungarian step finds each body's person again.
    again = [view("a", 5 + k, p) for k, p in enumerate(people)]
    again.append(view("b", 20, people[2]))
    clusters_again = tracker.associate(again, 1.033)
    person_of = {v.tracking_id: pid for pid, c in clusters.items() for v in c}
    assert {
        pid: [(v.sensor_id, v.tracking_id) for v in c] for pid, c in clusters_again.items()
    } == {
        person_of[0]: [("a", 5)],
        person_of[1]: [("a", 6)],
        person_of[2]: [("a", 7), ("b", 20)],
    }


def move_alone(track: Track, fused: npt.NDArray[np.float64], t_s: float) -> None:
    """One person's move as it was written before persons were moved together."""
    dt = t_s - track.last_seen_s
    moving = np.isfinite(fused[0]).all() and np.isfinite(track.joints[0]).all()
    if track.fused_once and 0 < dt < 0.5 and moving:
        velocity = (fused[0] - track.joints[0]) / dt
        velocity[1] = 0.0
        track.velocity = 0.6 * track.velocity + 0.4 * velocity
        x, y, z = track.velocity
        speed = float(np.sqrt((x * x + y * y) + z * z))  # the norm summed in index order
        if speed > 3.0:
            track.velocity *= 3.0 / speed
    track.joints = np.where(np.isfinite(fused), fused, track.joints)
    track.last_seen_s = t_s
    track.fused_once = True


def test_moving_persons_together_gives_each_persons_own_motion() -> None:
    rng = np.random.default_rng(8)
    tracker, alone = PersonTracker(FusionSettings()), PersonTracker(FusionSettings())
    for k, joints in enumerate(skeletons(rng, 8)):
        # Some seen long ago or never fused, some without a SpineBase, some far too fast.
        seen = 10.0 - [0.03, 0.03, 0.6, 0.03, 0.03, 0.1, 0.0, 0.03][k]
        if k == 2:  # seen too long ago, with a SpineBase: only its age keeps it still
            joints[0] = 0.0
        track = Track(k + 1, joints, seen, 0.0, velocity=rng.normal(0, 1, 3), fused_once=k != 3)
        tracker.tracks[k + 1] = track
        alone.tracks[k + 1] = Track(k + 1, joints.copy(), seen, 0.0, velocity=track.velocity.copy(),
                                    fused_once=track.fused_once)  # fmt: skip
    fused = tracker.tracks[1].joints + rng.normal(0.0, 0.05, (8, JOINT_COUNT, 3))
    fused[4] += 1.0  # 30 m/s
    fused[5, 0] = np.nan
    ids = [3, 1, 2, 4, 5, 6, 7, 8]
    joints, velocities = tracker.move_all(ids, fused, 10.0)
    for p, person_id in enumerate(ids):
        move_alone(alone.tracks[person_id], fused[p], 10.0)
        # What it returns stacked: each track's own, as it left them.
        assert joints[p].tobytes() == tracker.tracks[person_id].joints.tobytes()
        assert velocities[p].tobytes() == tracker.tracks[person_id].velocity.tobytes()
    for person_id, want in alone.tracks.items():
        got = tracker.tracks[person_id]
        np.testing.assert_array_equal(got.joints, want.joints)  # kept, not computed
        np.testing.assert_allclose(got.velocity, want.velocity, rtol=0.0, atol=1e-9)
        assert (got.last_seen_s, got.fused_once) == (want.last_seen_s, want.fused_once)
    assert any(np.linalg.norm(t.velocity) == pytest.approx(3.0) for t in alone.tracks.values())


def test_moving_everyone_at_once_gives_each_persons_own_motion() -> None:
    # Every person moves (the usual step).
    rng = np.random.default_rng(9)
    tracker, alone = PersonTracker(FusionSettings()), PersonTracker(FusionSettings())
    for k, joints in enumerate(skeletons(rng, 5)):
        joints[0] = rng.normal(0.0, 1.0, 3)  # a SpineBase for everyone
        track = Track(k + 1, joints, 9.97, 0.0, velocity=rng.normal(0, 1, 3), fused_once=True)
        tracker.tracks[k + 1] = track
        alone.tracks[k + 1] = Track(k + 1, joints.copy(), 9.97, 0.0, velocity=track.velocity.copy(),
                                    fused_once=True)  # fmt: skip
    fused = np.stack([t.joints for t in tracker.tracks.values()])
    fused = fused + rng.normal(0.0, 0.05, fused.shape)
    fused[2] += 1.0  # 33 m/s: clipped
    ids = [2, 1, 3, 5, 4]
    tracker.move_all(ids, fused, 10.0)
    for p, person_id in enumerate(ids):
        move_alone(alone.tracks[person_id], fused[p], 10.0)
    for person_id, want in alone.tracks.items():
        got = tracker.tracks[person_id]
        np.testing.assert_array_equal(got.joints, want.joints)  # kept, not computed
        np.testing.assert_allclose(got.velocity, want.velocity, rtol=0.0, atol=1e-9)
    assert all(np.any(t.velocity != 0.0) for t in alone.tracks.values())  # everyone moved
