"""Mirror labels through fast in-place turns (the crossing scenario's): the person's facing
without the sensors' turn towards themselves (``mirror.unbiased_facing``), and a stale view
turned over alone instead of the whole person (``mirror.redecide_views``)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from skelfuse.agent.sim.performer import BodyShape, Pose, pose_joints
from skelfuse.fusion.anatomy import facing_direction
from skelfuse.fusion.labels import LabelDoubt, label_views, unbiased_facings, views_alone
from skelfuse.fusion.settings import FusionSettings, MirrorSettings
from skelfuse.protocol.skeleton import MIRROR_PERMUTATION, JointId, TrackingState

LEAN = 0.5  # the simulator's facing_bias, FusionSettings.view_lean_fraction
HEADING = math.radians(30.0)


def body() -> np.ndarray:
    """A person at (0.4, −0.2) facing HEADING, knees a little bent (25, 3) metres."""
    pose = Pose(knee_flex_l=0.35, knee_flex_r=0.35, hip_flex_l=0.2, hip_flex_r=0.2)
    return pose_joints(BodyShape(1.75), pose, (0.4, -0.2), HEADING)


def sensor_at(yaw_deg: float) -> np.ndarray:
    """A sensor 3 m from the person, seeing them at ``yaw_deg`` from their front (1 m high)."""
    angle = HEADING + math.radians(yaw_deg)
    return np.array([0.4 + 3 * math.sin(angle), 1.0, -0.2 + 3 * math.cos(angle)])


def seen(yaw_deg: float) -> tuple[np.ndarray, bool]:
    """What a Kinect at ``yaw_deg`` reports, as the simulator models it (kinect_model._report):
    mirrored past 105°, turned towards the sensor by LEAN × its apparent yaw; and whether it
    mirrored it."""
    joints = body()
    mirrored = abs(yaw_deg) > 105.0
    apparent = math.radians(yaw_deg)
    if mirrored:
        joints = joints[list(MIRROR_PERMUTATION)]
        apparent -= math.copysign(math.pi, apparent)
    # The sensor sees the person at yaw θ when their facing is θ away from the direction to it;
    # turning the body towards the sensor lowers θ (a turn about +Y, as the simulator's).
    turn = LEAN * max(-math.pi / 2, min(math.pi / 2, apparent))
    c, s = math.cos(turn), math.sin(turn)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    pivot = joints[0].copy()
    return (joints - pivot) @ rotation.T + pivot, mirrored


def yaw_between(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two horizontal directions."""
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


TRUE_FACING = np.array([math.sin(HEADING), 0.0, math.cos(HEADING)])
YAWS = [-170.0, -120.0, -100.0, -60.0, -20.0, 0.0, 30.0, 80.0, 95.0, 110.0, 150.0, 180.0]


@pytest.mark.parametrize("yaw_deg", YAWS)
def test_unbiased_facing_takes_each_sensors_turn_out(yaw_deg: float) -> None:
    reported, mirrored = seen(yaw_deg)
    labelled = reported[list(MIRROR_PERMUTATION)] if mirrored else reported
    facing = unbiased_facings(
        labelled[None], sensor_at(yaw_deg)[None], np.array([mirrored]), [1], LEAN
    )[0]
    assert yaw_between(facing, TRUE_FACING) < 0.5
    # The view's own facing is turned towards the sensor (by up to 45°): what a fused
    # skeleton of such views inherits.
    turned = yaw_between(facing_direction(labelled), TRUE_FACING)
    assert turned == pytest.approx(
        LEAN * min(abs(yaw_deg) if not mirrored else 180 - abs(yaw_deg), 90), abs=0.5
    )


def test_unbiased_facing_averages_a_persons_views_and_rejects_a_bad_lean() -> None:
    yaws = [-100.0, 20.0, 150.0]
    views = [seen(y) for y in yaws]
    joints = np.stack([v[PERMUTE] if m else v for v, m in views])
    mirrored = np.array([m for _, m in views])
    sensors = np.stack([sensor_at(y) for y in yaws])
    facings = unbiased_facings(joints, sensors, mirrored, [2, 1], LEAN)
    assert yaw_between(facings[0], TRUE_FACING) < 0.5
    assert yaw_between(facings[1], TRUE_FACING) < 0.5
    with pytest.raises(ValueError, match="lean"):
        unbiased_facings(joints, sensors, mirrored, [3], 1.0)


PERMUTE = list(MIRROR_PERMUTATION)
LEGS = [
    JointId.KNEE_LEFT, JointId.KNEE_RIGHT, JointId.ANKLE_LEFT, JointId.ANKLE_RIGHT,
    JointId.FOOT_LEFT, JointId.FOOT_RIGHT,
]  # fmt: skip


def stale_side_view() -> tuple[np.ndarray, np.ndarray, list[tuple[str, int]], list[bool]]:
    """Three views of an old person; the side sensor at 92° has just stopped mirroring (the
    simulator's hysteresis: back below 95°), but its view is still remembered as mirrored. The
    two others do not see the legs: their anatomy says nothing either way (as standing straight
    in the crossing scenario's turns). Returns the views, the sensors, their keys and the truth
    (mirrored by the sensor)."""
    yaws = [92.0, -30.0, 170.0]
    views = [seen(y) for y in yaws]
    joints = np.stack([v for v, _ in views])
    joints[1:, LEGS] = np.nan
    sensors = np.stack([sensor_at(y) for y in yaws])
    keys = [("side", 1), ("front", 1), ("back", 1)]
    return joints, sensors, keys, [m for _, m in views]


def relabel(settings: FusionSettings) -> tuple[list[bool], int]:
    """One step of label_views on :func:`stale_side_view` with the labels remembered from the
    last step (the side view's stale); the decisions, and whether the person was swapped.
    A large hysteresis keeps the remembered labels, so the re-decision is what changes them."""
    joints, sensors, keys, truth = stale_side_view()
    remembered = dict(zip(keys, [True, truth[1], truth[2]], strict=True))
    states = np.full((3, 25), TrackingState.TRACKED, dtype=np.uint8)
    reference = body()
    doubt = LabelDoubt(sensors=frozenset(k[0] for k in keys), born_s=-10.0, last_s=-1 / 30)
    mirrored, _, swapped = label_views(
        joints, states, sensors, keys, [3], [reference], TRUE_FACING[None], [remembered],
        settings, [doubt], 0.0,
    )  # fmt: skip
    return [bool(m) for m in mirrored], int(swapped.sum())


def test_a_stale_view_turns_alone_when_the_other_views_do_not_doubt() -> None:
    s = FusionSettings(mirror=MirrorSettings(hysteresis_m=1.0, redecide=True))
    _, _, _, truth = stale_side_view()
    # Before: the whole person turns over, which makes the two right views wrong.
    whole, swaps = relabel(replace(s, mirror=replace(s.mirror, redecide_views=1)))
    assert swaps == 1
    assert whole == [truth[0], not truth[1], not truth[2]]  # side right, the others wrong
    # With it: only the stale view turns; the track stays.
    alone, swaps = relabel(replace(s, mirror=replace(s.mirror, redecide_views=2)))
    assert swaps == 0
    assert alone == truth


def test_views_alone_leaves_young_persons_and_wide_doubt_to_the_whole_turn() -> None:
    s = FusionSettings(mirror=MirrorSettings(redecide_views=2))
    old = LabelDoubt(born_s=0.0)
    one = np.array([2.0, 0.1, -0.3])
    assert views_alone(one, old, 5.0, s).tolist() == [True, False, False]
    assert views_alone(np.array([2.0, 0.8, -0.3]), old, 5.0, s) is None  # two views doubt
    assert views_alone(one, old, 0.5, s) is None  # young: its labels were a guess
    assert views_alone(np.array([2.0]), old, 5.0, s) is None  # one view: it is the person
    assert (
        views_alone(one, old, 5.0, replace(s, mirror=replace(s.mirror, redecide_views=1))) is None
    )
