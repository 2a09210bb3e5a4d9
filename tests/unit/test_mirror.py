"""Mirrored-view detection: which views have left and right swapped."""

from __future__ import annotations

import numpy as np

from skelfuse.agent.sim.performer import BodyShape, Pose, pose_joints
from skelfuse.fusion.mirror import choose_labelling
from skelfuse.protocol.skeleton import MIRROR_PERMUTATION

WALK = Pose(hip_flex_l=0.3, hip_flex_r=-0.3, knee_flex_l=0.6, knee_flex_r=0.1,
            shoulder_flex_l=-0.3, shoulder_flex_r=0.3)  # fmt: skip
FRONT = np.array([0.0, 1.0, 2.5])  # the person faces +Z
BACK = np.array([0.0, 1.0, -2.5])
SIDE = np.array([2.5, 1.0, 0.0])


def person(pose: Pose = WALK) -> np.ndarray:
    return pose_joints(BodyShape(1.75), pose, (0.0, 0.0), 0.0)


def mirrored(joints: np.ndarray) -> np.ndarray:
    return joints[list(MIRROR_PERMUTATION)]


def test_back_view_is_found_among_front_and_side() -> None:
    truth = person()
    views = np.stack([truth, mirrored(truth), truth])
    result = choose_labelling(views, np.stack([FRONT, BACK, SIDE]))
    assert result.tolist() == [False, True, False]


def test_a_single_back_view_is_found_from_anatomy() -> None:
    truth = person()
    assert choose_labelling(mirrored(truth)[None], BACK[None]).tolist() == [True]
    assert choose_labelling(truth[None], FRONT[None]).tolist() == [False]


def test_all_views_from_behind_are_corrected_with_a_track() -> None:
    truth = person()
    views = np.stack([mirrored(truth), mirrored(truth)])
    sensors = np.stack([BACK, BACK + [1.0, 0.0, 0.0]])
    result = choose_labelling(views, sensors, reference=truth)
    assert result.tolist() == [True, True]


def test_hysteresis_keeps_an_ambiguous_decision() -> None:
    standing = person(Pose())
    # Side-on, standing still: both labellings are nearly as good; keep the previous one.
    views = np.stack([standing, standing])
    result = choose_labelling(views, np.stack([SIDE, SIDE]), previous=np.array([0, 0]))
    assert result.tolist() == [False, False]


def test_no_views() -> None:
    assert choose_labelling(np.zeros((0, 25, 3)), np.zeros((0, 3))).shape == (0,)


def test_several_persons_at_once_decide_as_one_by_one() -> None:
    from skelfuse.fusion.anatomy import facing_direction
    from skelfuse.fusion.mirror import choose_labellings

    rng = np.random.default_rng(7)
    truth = person()
    sensors_all = np.stack([FRONT, BACK, SIDE, -SIDE])
    persons, sensors, references, previous = [], [], [], []
    for n in (1, 2, 3, 4, 4):
        views = np.stack([truth + rng.normal(scale=0.02, size=truth.shape) for _ in range(n)])
        flip = rng.random(n) < 0.5
        views[flip] = views[flip][:, list(MIRROR_PERMUTATION)]
        persons.append(views)
        sensors.append(sensors_all[:n])
        references.append(None if n == 2 else truth)
        previous.append(rng.integers(-1, 2, size=n))
    facings = np.stack([facing_direction(truth)] * len(persons))
    together, factors = choose_labellings(
        np.concatenate(persons),
        np.concatenate(sensors),
        [len(p) for p in persons],
        references,
        facings,
        np.concatenate(previous),
        geometry_weight_m=0.15,
        hysteresis_m=0.05,
        track_weight=1.0,
        anatomy_weight_m=0.1,
        rom_scale_deg=15.0,
    )
    alone = np.concatenate(
        [
            choose_labelling(v, s, r, p)
            for v, s, r, p in zip(persons, sensors, references, previous, strict=True)
        ]
    )
    assert together.tolist() == alone.tolist()
    assert factors is not None and factors.shape == (len(together), 2, 25)
