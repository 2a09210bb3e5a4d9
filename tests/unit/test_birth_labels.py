"""Birth labelling that cannot lock in a guess (issue 10 item 1): a person first seen from
behind, legs out of view, by one sensor, then from the front and sides by two more."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skelfuse.agent.sim.performer import BodyShape, Pose, pose_joints
from skelfuse.fusion.labels import LabelDoubt, evidence_against, redecide
from skelfuse.fusion.pipeline import FusionPipeline
from skelfuse.fusion.settings import FusionSettings, MirrorSettings
from skelfuse.fusion.views import View
from skelfuse.protocol.skeleton import MIRROR_PERMUTATION, JointId, TrackingState

J = JointId
LEGS = [J.KNEE_LEFT, J.KNEE_RIGHT, J.ANKLE_LEFT, J.ANKLE_RIGHT, J.FOOT_LEFT, J.FOOT_RIGHT]
REAR = np.array([0.0, 1.0, -1.1])  # close behind the person, who faces +Z
FRONT_SIDES = {
    "left": np.array([2.6 * math.sin(math.radians(40)), 1.0, 2.6 * math.cos(math.radians(40))]),
    "right": np.array([-2.6 * math.sin(math.radians(40)), 1.0, 2.6 * math.cos(math.radians(40))]),
}
DT = 1 / 30


def body(t_s: float) -> np.ndarray:
    """The person standing at the origin facing +Z, breathing a little (25, 3) metres."""
    relaxed = Pose(shoulder_abd_l=0.1, shoulder_abd_r=0.1, elbow_flex_l=0.26,
                   elbow_flex_r=0.26, knee_flex_l=0.05, knee_flex_r=0.05)  # fmt: skip
    return pose_joints(BodyShape(1.75), relaxed, (0.002 * math.sin(t_s), 0.0), 0.0)


def rear_view(t_s: float) -> View:
    """What the sensor behind reports: a front-facing body, so left and right swapped, with
    the legs below its field of view."""
    joints = body(t_s)[list(MIRROR_PERMUTATION)]
    states = np.full(25, TrackingState.TRACKED, dtype=np.uint8)
    joints[LEGS] = np.nan
    states[LEGS] = TrackingState.NOT_TRACKED
    return View("rear", 1, joints, states, REAR)


def front_views(t_s: float) -> list[View]:
    states = np.full(25, TrackingState.TRACKED, dtype=np.uint8)
    return [View(name, 2, body(t_s), states, at) for name, at in FRONT_SIDES.items()]


def run(settings: FusionSettings, steps: int = 20) -> list[tuple[str, ...]]:
    """The sensors swapped back for the person, step by step: 3 steps with the rear sensor
    alone (the birth), then all three."""
    pipeline = FusionPipeline(settings)
    out: list[tuple[str, ...]] = []
    for i in range(steps):
        t = i * DT
        views = [rear_view(t)] + (front_views(t) if i >= 3 else [])
        persons = pipeline.update(views, t)
        out.append(persons[0].mirrored if persons else ())
    return out


def test_without_redeciding_the_birth_guess_stays() -> None:
    # The behaviour before mirror_redecide, pinned: the rear view alone cannot tell its sides,
    # it is kept as reported, and the front views are then labelled to agree with the track.
    labels = run(FusionSettings(mirror=MirrorSettings(redecide=False)))
    assert labels[-1] == ("left", "right")


def test_a_track_born_mirrored_is_labelled_right_once_front_views_join() -> None:
    labels = run(FusionSettings())  # mirror_redecide is the default
    joined = 3
    right = [i for i, m in enumerate(labels) if m == ("rear",)]
    assert right and right[0] - joined <= 0.5 / DT  # within 0.5 s of the front views joining
    assert all(m == ("rear",) for m in labels[right[0] :])  # and it stays right


def test_a_view_without_legs_gives_next_to_no_evidence() -> None:
    from skelfuse.fusion.anatomy import rom_factors_and_forward
    from skelfuse.fusion.mirror import labellings

    rear = rear_view(0.0).joints_world
    factors, _ = rom_factors_and_forward(labellings(rear[None]).reshape(-1, 25, 3), 15.0)
    both = factors.reshape(1, 2, 25)
    front = body(0.0)[None]
    front_factors, _ = rom_factors_and_forward(labellings(front).reshape(-1, 25, 3), 15.0)
    blind = evidence_against(both, np.array([False]), [1])[0]
    # The front view labelled the wrong way round: its feet point backwards.
    seeing = evidence_against(front_factors.reshape(1, 2, 25), np.array([True]), [1])[0]
    assert abs(blind) < 0.5 < seeing


@pytest.mark.parametrize("young", [True, False])
def test_redecide_needs_evidence_that_persists_unless_a_sensor_joins_a_young_track(
    young: bool,
) -> None:
    s = FusionSettings(mirror=MirrorSettings(redecide=True))
    doubt = LabelDoubt()
    start = 0.0 if young else -10.0
    assert not redecide(doubt, 0.0, frozenset({"a"}), start, s)
    # A sensor joins with evidence just under the full threshold.
    joined = redecide(doubt, 0.9 * s.mirror.redecide_evidence, frozenset({"a", "b"}), 0.1, s)
    assert joined is young
    if not young:
        # The same evidence again a frame later adds up past the threshold.
        assert redecide(doubt, 0.9 * s.mirror.redecide_evidence, frozenset({"a", "b"}), 0.133, s)
    assert doubt.against == 0.0 and doubt.swaps == 1
