"""Hand states from sensor to fused person: Kinect v2 source, Azure (none), simulator, fusion."""

from __future__ import annotations

import importlib
from collections import deque

import numpy as np
import numpy.typing as npt
import pytest

from skelfuse.agent.sim.hands import simulated_hands
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sources.sim import SimSource
from skelfuse.fusion.hands import fuse_hands
from skelfuse.fusion.pipeline import views_at
from skelfuse.fusion.sensors import SensorState, TimedFrame
from skelfuse.fusion.views import FusedPerson
from skelfuse.protocol.hands import UNKNOWN_HANDS, HandConfidence, Hands, HandState
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Body, Frame, decode, encode
from tests.unit.test_sdk_sources import (  # noqa: F401 (fixtures)
    FakeClock,
    _azure_body,
    _images,
    fake_k4a,
    fake_pykinect2,
)

OP, C, L = HandState.OPEN, HandState.CLOSED, HandState.LASSO
HI, LO = HandConfidence.HIGH, HandConfidence.LOW
TRACKED = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)


def states_with(**joint_states: int) -> npt.NDArray[np.uint8]:
    states = TRACKED.copy()
    for name, value in joint_states.items():
        states[JointId[name]] = value
    return states


# --- sources ------------------------------------------------------------------------------------


@pytest.mark.usefixtures("fake_pykinect2")
def test_kinect_v2_source_passes_hand_states_through() -> None:
    from skelfuse.agent.sources.kinect_v2 import KinectV2Source, import_pykinect2

    _, runtime = import_pykinect2()
    joints = np.arange(75, dtype=np.float64).reshape(25, 3) / 100.0
    body = runtime.KinectBody(5, joints, [2] * 25, hands=(3, 4, 1, 0))
    odd = runtime.KinectBody(6, joints + 1.0, [2] * 25, hands=(9, 2, 3, 1))  # not SDK values
    runtime.SCRIPT[:] = [runtime.KinectBodyFrameData([body, odd], (0, 1, 0, 1), 10_000_000)]
    source = KinectV2Source(wall_clock_ns=FakeClock(), sleep=lambda s: None)
    capture = source.next_capture(0.1)
    assert capture is not None
    assert capture.bodies[0].hands == Hands(C, L, HI, LO)
    assert capture.bodies[1].hands == Hands(HandState.UNKNOWN, OP, LO, HI)
    decoded = decode(encode(Frame(1, capture.t_capture_ns, capture.bodies, capture.floor)))
    assert isinstance(decoded, Frame)
    assert decoded.bodies[0].hands == Hands(C, L, HI, LO)


@pytest.mark.usefixtures("fake_k4a")
def test_azure_kinect_bodies_have_no_hand_states() -> None:
    from skelfuse.agent.sources.azure_kinect import AzureKinectSource

    fake_k4a_module = importlib.import_module("pykinect_azure")

    joints, levels = _azure_body(np.random.default_rng(1))
    fake_k4a_module.k4a.SCRIPT[:] = [(1_000_000, *_images())]
    fake_k4a_module.k4abt.DETECT = lambda depth, ir, calibration: [(7, joints, levels)]
    capture = AzureKinectSource(wall_clock_ns=FakeClock()).next_capture(0.1)
    assert capture is not None and capture.bodies[0].hands is None


# --- simulator ----------------------------------------------------------------------------------


def standing(
    hand_left: tuple[float, float, float], hand_right: tuple[float, float, float]
) -> npt.NDArray[np.float32]:
    joints = np.zeros((JOINT_COUNT, 3), dtype=np.float32)
    joints[:, 2] = 2.5
    joints[JointId.SPINE_MID] = (0.0, 0.3, 2.5)
    joints[JointId.SHOULDER_LEFT] = (-0.2, 0.6, 2.5)
    joints[JointId.SHOULDER_RIGHT] = (0.2, 0.6, 2.5)
    joints[JointId.HAND_LEFT] = hand_left
    joints[JointId.HAND_RIGHT] = hand_right
    return joints


def test_simulated_hands_follow_the_pose() -> None:
    fist_at_chest, hanging, raised = (0.05, 0.35, 2.4), (0.3, -0.1, 2.5), (0.3, 0.9, 2.5)
    assert simulated_hands(standing(fist_at_chest, hanging), TRACKED, 1, 0.0) == Hands(
        C, OP, HI, LO
    )
    raised_both = standing(raised, raised)
    seen = {simulated_hands(raised_both, TRACKED, 1, float(t)).left for t in range(40)}
    assert seen == {OP, L}  # Lasso about one second in twenty
    lasso_seconds = [t for t in range(40) if simulated_hands(raised_both, TRACKED, 1, t).left == L]
    assert len(lasso_seconds) == 2
    hidden = states_with(WRIST_RIGHT=TrackingState.INFERRED)
    assert simulated_hands(raised_both, hidden, 1, 0.5).right == HandState.NOT_TRACKED


def test_sim_source_hand_states_change_nothing_else() -> None:
    pose = look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0))
    with_hands = SimSource(ProceduralPerformer(2), pose, seed=4, wall_clock_ns=lambda: 0)
    without = SimSource(
        ProceduralPerformer(2), pose, seed=4, wall_clock_ns=lambda: 0, hand_states=False
    )
    for true_ns in range(0, 2_000_000_000, 100_000_000):
        a, b = with_hands.capture_at(true_ns), without.capture_at(true_ns)
        assert [body.hands is not None for body in a.bodies] == [True] * len(a.bodies)
        assert all(body.hands is None for body in b.bodies)
        for x, y in zip(a.bodies, b.bodies, strict=True):
            assert x.tracking_id == y.tracking_id
            np.testing.assert_array_equal(x.joints_m, y.joints_m)
            np.testing.assert_array_equal(x.states, y.states)


# --- fusion -------------------------------------------------------------------------------------


def test_no_view_with_hands_gives_none() -> None:
    assert fuse_hands([(None, TRACKED, False), (None, TRACKED, True)]) is None
    assert fuse_hands([]) is None


def test_most_votes_win_among_tracked_wrists() -> None:
    reports = [
        (Hands(C, OP, LO, HI), TRACKED, False),
        (Hands(C, C, LO, LO), TRACKED, False),
        (Hands(OP, L, HI, HI), states_with(WRIST_LEFT=TrackingState.INFERRED), False),
        (None, TRACKED, False),
    ]
    # Left: Closed twice (Low) beats the inferred wrist's Open. Right: one vote each; Open and
    # Lasso are High, Closed Low; Open before Lasso by value.
    assert fuse_hands(reports) == Hands(C, OP, LO, HI)


def test_unknown_and_not_tracked_do_not_vote() -> None:
    reports = [
        (Hands(HandState.UNKNOWN, HandState.NOT_TRACKED, HI, HI), TRACKED, False),
        (Hands(HandState.UNKNOWN, OP, HI, LO), states_with(WRIST_RIGHT=0), False),
    ]
    assert fuse_hands(reports) == UNKNOWN_HANDS


def test_a_mirrored_view_votes_for_the_other_hand() -> None:
    reports = [
        (Hands(L, C, HI, HI), TRACKED, True),  # the sensor's left is the person's right
        (Hands(C, OP, LO, LO), states_with(WRIST_LEFT=1), False),  # only its right hand votes
    ]
    fused = fuse_hands(reports)
    assert fused == Hands(C, L, HI, HI)


def test_ties_do_not_depend_on_view_order() -> None:
    reports = [(Hands(L, OP, HI, LO), TRACKED, False), (Hands(OP, L, HI, LO), TRACKED, False)]
    assert fuse_hands(reports) == fuse_hands(reports[::-1]) == Hands(OP, OP, HI, LO)


def test_views_carry_the_nearer_frames_hands() -> None:
    sensor = SensorState("a", "kinect_v2", "0", b"a", 30.0, connected=True)
    joints = np.zeros((JOINT_COUNT, 3), dtype=np.float32)
    joints[:, 2] = 2.0
    frames = [
        Frame(i, i, (Body(9, joints, TRACKED, Hands(hand, OP, HI, HI)),)) for i, hand in ((1, C),
                                                                                     (2, L))
    ]  # fmt: skip
    sensor.frames = deque([TimedFrame(10.0, frames[0]), TimedFrame(10.0 + 1 / 30, frames[1])])
    pose = np.eye(4)
    early = views_at([sensor], lambda _: pose, 10.01, 0.2)
    late = views_at([sensor], lambda _: pose, 10.03, 0.2)
    assert [v.hands for v in early] == [Hands(C, OP, HI, HI)]
    assert [v.hands for v in late] == [Hands(L, OP, HI, HI)]
    sensor.frames = deque([TimedFrame(10.0, Frame(1, 1, (Body(9, joints, TRACKED),)))])
    assert [v.hands for v in views_at([sensor], lambda _: pose, 10.0, 0.2)] == [None]


@pytest.mark.parametrize("hands", [None, Hands(C, OP, HI, LO)])
def test_fused_person_gets_the_hands(hands: Hands | None) -> None:
    from skelfuse.fusion.pipeline import FusionPipeline
    from skelfuse.fusion.settings import FusionSettings

    pipeline = FusionPipeline(FusionSettings())
    sensors = []
    frames_joints = ProceduralPerformer(1).joints_at(1.0)[0].astype(np.float32)
    for name in ("a", "b"):
        sensor = SensorState(name, "sim", "0", name.encode(), 30.0, connected=True)
        body = Body(3, frames_joints, TRACKED, hands)
        sensor.frames = deque([TimedFrame(t / 30, Frame(t, t, (body,))) for t in range(30)])
        sensors.append(sensor)
    persons: list[FusedPerson] = []
    for t in range(5, 30):
        persons, _ = pipeline.step(sensors, lambda _: np.eye(4), t / 30, 0.2)
    assert len(persons) == 1
    assert persons[0].hands == hands
