"""A single arm or leg pair reported left for right is put right (fusion/limb_labels.py)."""

from __future__ import annotations

import math

import numpy as np

from skelfuse.agent.sim.performer import BodyShape, Pose, pose_joints
from skelfuse.fusion.limb_labels import LIMBS, swap_limbs

POSE = Pose(shoulder_abd_l=math.radians(40), shoulder_flex_r=math.radians(60), hip_flex_l=0.5)
BODY = pose_joints(BodyShape(1.75), POSE, (0.0, 0.0), 0.0)
ARMS, LEGS = (LIMBS[0], LIMBS[1]), (LIMBS[2][:3], LIMBS[3][:3])


def _views(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(BODY[None], count, axis=0) + rng.normal(0.0, 0.01, (count, 25, 3))


def _swap(view: np.ndarray, pair: tuple[np.ndarray, np.ndarray]) -> None:
    left, right = pair
    view[left], view[right] = view[right].copy(), view[left].copy()


def _run(views: np.ndarray, track: np.ndarray | None = None) -> np.ndarray:
    states = np.full(views.shape[:2], 2, np.uint8)
    tracks = (
        (np.zeros((1, 25, 3)), np.zeros(1, dtype=bool))
        if track is None
        else (track[None], np.ones(1, dtype=bool))
    )
    starts = np.array([0, len(views)], dtype=np.intp)
    return swap_limbs(views, states, np.ones(views.shape[:2]), starts, tracks)


def test_a_view_with_its_arms_swapped_is_put_right_by_the_others() -> None:
    truth = _views(3)
    views = truth.copy()
    _swap(views[1], ARMS)
    swapped = _run(views)
    assert swapped.tolist() == [[False, False], [True, False], [False, False]]
    np.testing.assert_allclose(views, truth, atol=1e-12)
    assert not _run(truth.copy()).any()  # nothing swapped: nothing done


def test_legs_put_right_at_hip_width_and_left_alone_when_they_nearly_touch() -> None:
    standing = pose_joints(BodyShape(1.75), Pose(), (0.0, 0.0), 0.0)
    views = np.repeat(standing[None], 3, axis=0)
    _swap(views[2], LEGS)  # hip width apart: a real swap, put right
    assert _run(views).tolist() == [[False, False], [False, False], [False, True]]
    close = standing.copy()
    close[LEGS[1]] = close[LEGS[0]] + (0.06, 0.0, 0.0)  # legs crossed, 6 cm apart
    views = np.repeat(close[None], 3, axis=0)
    _swap(views[2], LEGS)  # too little evidence, and it matters little
    assert not _run(views).any()


def test_two_views_need_the_track_to_agree_and_one_view_is_never_judged() -> None:
    truth = _views(2, seed=1)
    views = truth.copy()
    _swap(views[0], ARMS)
    assert not _run(views.copy()).any()  # no track: which of the two is swapped is unknown
    assert _run(views, track=BODY).tolist() == [[True, False], [False, False]]
    np.testing.assert_allclose(views, truth, atol=1e-12)
    wrong_track = BODY.copy()
    _swap(wrong_track, ARMS)  # a track that went wrong cannot turn two views that agree
    assert not _run(truth.copy(), track=wrong_track).any()
    alone = truth[:1].copy()
    _swap(alone[0], ARMS)
    assert not _run(alone, track=BODY).any()
