"""The server with moving sensors (issue 15 item 2): frames placed in their tracking space by
their own pose, one world transform per space, the sensor's world position at the instant, and
mutual capture by two head-mounted sensors fused where the truth is. Injected clocks only."""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import numpy.typing as npt

from skelfuse.agent.sim.performer import standing_pose
from skelfuse.calibration.store import Calibration, SensorCalibration, SpaceCalibration
from skelfuse.fusion.extrapolation import views_with_late
from skelfuse.fusion.sensors import TimedFrame, placed_in_space, world_position
from skelfuse.fusion.settings import HubSettings
from skelfuse.fusion.spaces import split_by_space
from skelfuse.fusion.world_views import views_at
from skelfuse.protocol.constants import MOVING_SENSORS
from skelfuse.protocol.sensor_pose import pose_from_matrix, pose_matrix
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.transform import (
    Matrix4,
    apply,
    invert,
    look_at_pose,
    pose_from_position_yaw_pitch,
)
from skelfuse.protocol.wire import Body, Frame, Hello, SensorPose, Welcome, encode
from skelfuse.server.hub import FusionHub

T0 = 1_800_000_000.0
FPS = 30.0
TRACKED = np.full(JOINT_COUNT, 2, dtype=np.uint8)
# The tracking space (a headset system's room) is turned and shifted against the world.
WORLD_FROM_SPACE = pose_from_position_yaw_pitch((1.0, 0.0, -2.0), 35.0)


def body(tracking_id: int, joints_sensor: npt.NDArray[np.float64]) -> Body:
    return Body(tracking_id, joints_sensor.astype(np.float32), TRACKED.copy())


def seen(
    world_from_sensor: Matrix4, joints_world: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """World joints as a sensor at ``world_from_sensor`` reports them (its camera frame)."""
    return apply(invert(world_from_sensor), joints_world)


def space_pose(world_from_sensor: Matrix4) -> SensorPose:
    """The sensor's pose as its tracking space knows it (``T_space_from_sensor``)."""
    return pose_from_matrix(invert(WORLD_FROM_SPACE) @ world_from_sensor)


def moving_hello(sensor_id: str, space: str = "room") -> bytes:
    return encode(Hello(sensor_id, "sim", "t", FPS, 0, moving=True, pose_space=space))


# --- placement ---------------------------------------------------------------------------------


def test_a_frame_is_placed_in_its_space_by_its_own_pose() -> None:
    truth = standing_pose() + [0.5, 0.0, 2.0]
    world_from_sensor = look_at_pose((0.0, 1.6, 0.0), (0.5, 1.0, 2.0))
    frame = Frame(
        7,
        1,
        (body(3, seen(world_from_sensor, truth)),),
        (0.0, 1.0, 0.0, 1.6),
        space_pose(world_from_sensor),
    )
    placed = placed_in_space(frame)
    in_world = apply(WORLD_FROM_SPACE, placed.bodies[0].joints_m)
    np.testing.assert_allclose(in_world, truth, atol=2e-6)
    assert placed.pose == frame.pose and placed.seq == 7
    assert placed.bodies[0].tracking_id == 3
    # The floor plane moves with the bodies: every placed floor point satisfies it.
    assert placed.floor is not None
    a, b, c, d = placed.floor
    point_sensor = np.array([0.3, -1.6, 2.0])  # on the sensor-frame floor y = -1.6
    point_space = apply(pose_matrix(frame.pose), point_sensor)  # type: ignore[arg-type]
    assert abs(a * point_space[0] + b * point_space[1] + c * point_space[2] + d) < 1e-9
    assert math.isclose(math.hypot(a, b, c), 1.0, rel_tol=1e-12)


def test_the_sensor_stands_where_its_poses_put_it_at_the_instant() -> None:
    first = pose_from_position_yaw_pitch((0.0, 1.6, 0.0), 0.0)
    second = pose_from_position_yaw_pitch((0.2, 1.6, 0.1), 30.0)
    frames = deque(
        TimedFrame(t, Frame(i, 0, (), None, pose_from_matrix(pose)))
        for i, (t, pose) in enumerate(((10.0, first), (10.1, second)))
    )
    got = world_position(frames, 10.025, WORLD_FROM_SPACE)
    expected = WORLD_FROM_SPACE[:3, :3] @ [0.05, 1.6, 0.025] + WORLD_FROM_SPACE[:3, 3]
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # After the newest frame it is held there, as the bodies are.
    held = world_position(frames, 10.13, WORLD_FROM_SPACE)
    np.testing.assert_allclose(held, apply(WORLD_FROM_SPACE, [0.2, 1.6, 0.1]), atol=1e-12)


# --- the hub -----------------------------------------------------------------------------------


def test_the_welcome_announces_moving_sensors_to_every_agent() -> None:
    hub = FusionHub(HubSettings())
    for routing_id, hello in (
        (b"a", moving_hello("head-a")),
        (b"c", encode(Hello("cam", "sim", "t", FPS, 0))),
    ):
        (welcome,) = hub.handle_message(routing_id, [hello], T0, 0.0)
        assert isinstance(welcome, Welcome) and MOVING_SENSORS in welcome.features


def test_a_moving_frame_without_a_pose_is_counted_and_dropped() -> None:
    hub = FusionHub(HubSettings())
    hub.handle_message(b"a", [moving_hello("head-a")], T0, 0.0)
    pose = space_pose(np.eye(4))
    sent = [Frame(1, round(T0 * 1e9), (), None, pose), Frame(2, round((T0 + 0.033) * 1e9), ())]
    sent.append(Frame(3, round((T0 + 0.066) * 1e9), (), None, pose))
    for k, frame in enumerate(sent):
        assert hub.handle_message(b"a", [encode(frame)], T0 + 0.07 + k * 1e-3, 0.1) == []
    sensor = hub.sensors["head-a"]
    assert sensor.frames_rejected == {"no_pose": 1}
    assert [timed.frame.seq for timed in sensor.frames] == [1, 3]
    # Counted once: the unposed frame was delivered, so it is no sequence gap as well.
    assert sensor.sequence_gaps == 0


def test_each_lost_frame_is_counted_once_rejected_or_never_sent() -> None:
    hub = FusionHub(HubSettings())
    hub.handle_message(b"a", [moving_hello("head-a")], T0, 0.0)
    pose = space_pose(np.eye(4))

    def send(seq: int, captured_s: float, posed: bool = True) -> None:
        frame = Frame(seq, round(captured_s * 1e9), (), None, pose if posed else None)
        hub.handle_message(b"a", [encode(frame)], T0 + seq / FPS + 0.004, seq / FPS)

    send(1, T0 + 1 / FPS)
    send(2, T0 + 2 / FPS, posed=False)  # no_pose
    send(3, T0 + 3 / FPS - 5.0)  # captured 5 s before it arrived: stale
    send(5, T0 + 5 / FPS)  # 4 never came (the agent did not send an unposed capture): a gap
    sensor = hub.sensors["head-a"]
    assert sensor.frames_rejected == {"no_pose": 1, "stale": 1}
    assert sensor.sequence_gaps == 1
    assert [timed.frame.seq for timed in sensor.frames] == [1, 5]
    send(5, T0 + 5 / FPS)  # a repeated seq is refused and does not move the counter back
    assert sensor.frames_rejected["replayed_seq"] == 1 and sensor.sequence_gaps == 1


def test_a_fixed_sensor_is_unchanged_by_a_pose_it_did_not_need() -> None:
    # A v1 agent: no moving flag; its frames are fused in its own frame, as before, even if a
    # (buggy) agent sent a pose.
    hub = FusionHub(HubSettings())
    world_from_sensor = look_at_pose((0.0, 1.0, 0.0), (0.0, 1.0, 3.0))
    hello = Hello(
        "cam", "sim", "t", FPS, 0, pose_hint=world_from_sensor, pose_hint_source="sim_truth"
    )
    hub.handle_message(b"c", [encode(hello)], T0, 0.0)
    joints = seen(world_from_sensor, standing_pose() + [0.0, 0.0, 3.0])
    frame = Frame(1, round(T0 * 1e9), (body(1, joints),), None, space_pose(np.eye(4)))
    hub.handle_message(b"c", [encode(frame)], T0 + 0.01, 0.01)
    kept = hub.sensors["cam"].frames[-1].frame.bodies[0].joints_m
    assert kept.tobytes() == joints.astype(np.float32).tobytes()
    pose, source = hub.pose_of("cam")
    assert source == "sim_truth" and pose is not None
    np.testing.assert_array_equal(pose, world_from_sensor)


def test_one_transform_per_space_from_the_calibration_a_hint_or_the_floor() -> None:
    def hub_with(calibration: Calibration | None, *hellos: Hello) -> FusionHub:
        hub = FusionHub(HubSettings(), calibration)
        for k, hello in enumerate(hellos):
            hub.handle_message(bytes([k]), [encode(hello)], T0, 0.0)
        return hub

    a = Hello("head-a", "sim", "t", FPS, 0, moving=True, pose_space="room")
    b = Hello("head-b", "sim", "t", FPS, 0, moving=True, pose_space="room")
    other = Hello("head-c", "sim", "t", FPS, 0, moving=True, pose_space="hall")
    fixed = Hello("cam", "sim", "t", FPS, 0)
    # The space alone: it is the world (OpenVR's standing space: +Y up, floor at y = 0).
    lone = hub_with(None, a, b, fixed)
    assert lone.pose_of("head-a")[1] == lone.pose_of("head-b")[1] == "floor"
    np.testing.assert_array_equal(lone.pose_of("head-a")[0], np.eye(4))  # type: ignore[arg-type]
    assert lone.pose_of("cam") == (None, "uncalibrated")
    # A second space, or a calibrated fixed sensor: no longer the only frame of reference.
    assert hub_with(None, a, other).pose_of("head-a") == (None, "uncalibrated")
    fixed_stored = Calibration(1, 0.0, {"cam": SensorCalibration(np.eye(4), "points")})
    assert hub_with(fixed_stored, a, fixed).pose_of("head-a") == (None, "uncalibrated")
    # A stored space serves all its sensors; a moving sensor's stored pose is not its own.
    stored = Calibration(
        2,
        0.0,
        {"head-a": SensorCalibration(np.eye(4), "points")},
        spaces={"room": SpaceCalibration(WORLD_FROM_SPACE, "manual")},
    )
    both = hub_with(stored, a, b, other)
    for sensor_id in ("head-a", "head-b"):
        pose, source = both.pose_of(sensor_id)
        assert source == "stored" and pose is WORLD_FROM_SPACE
    assert both.pose_of("head-c") == (None, "uncalibrated")
    # A moving sensor's hint is its space's pose.
    hinted = Hello(
        "head-h", "sim", "t", FPS, 0, pose_hint=WORLD_FROM_SPACE, pose_hint_source="sim_truth",
        moving=True, pose_space="hall",
    )  # fmt: skip
    pose, source = hub_with(None, a, hinted, other).pose_of("head-c")
    assert source == "sim_truth" and pose is not None
    np.testing.assert_array_equal(pose, WORLD_FROM_SPACE)


def test_a_run_that_solved_a_moving_sensor_stores_its_space() -> None:
    hub = FusionHub(HubSettings())
    hub.handle_message(b"a", [moving_hello("head-a")], T0, 0.0)
    hub.handle_message(b"c", [encode(Hello("cam", "sim", "t", FPS, 0))], T0, 0.0)
    solved = {
        "head-a": SensorCalibration(WORLD_FROM_SPACE, "skeleton", 12.0),
        "cam": SensorCalibration(np.eye(4), "skeleton", 9.0),
    }
    fixed, spaces = split_by_space(hub.sensors, solved)
    assert list(fixed) == ["cam"] and list(spaces) == ["room"]
    assert spaces["room"].T_world_from_space is WORLD_FROM_SPACE
    assert spaces["room"].residual_mm == 12.0 and spaces["room"].details["sensor"] == "head-a"


# --- mutual capture ----------------------------------------------------------------------------


def wearer_truth(k: int, t_s: float) -> npt.NDArray[np.float64]:
    """Wearer ``k`` (0 or 1) at time ``t_s``: 3 m apart facing each other, walking sideways at
    0.3 m/s (world joints (25, 3))."""
    person = standing_pose(1.75 if k == 0 else 1.65)
    if k == 1:  # turned to face -Z (the other wearer)
        person = person * [-1.0, 1.0, -1.0]
    return person + [0.3 * t_s * (1 if k == 0 else -1), 0.0, 3.0 * k]


def head_sensor(k: int, t_s: float) -> Matrix4:
    """Wearer ``k``'s head-mounted sensor: at their head, looking at the other wearer's chest,
    the head turning ±25° in yaw and ±10° in pitch (up to ~160°/s)."""
    own, theirs = wearer_truth(k, t_s), wearer_truth(1 - k, t_s)
    head = own[3] + [0.0, 0.08, 0.1 if k == 0 else -0.1]
    aim = look_at_pose(tuple(head), tuple(theirs[1]))  # type: ignore[arg-type]
    turn = pose_from_position_yaw_pitch(
        (0.0, 0.0, 0.0), 25.0 * math.sin(6.0 * t_s + k), 10.0 * math.sin(4.0 * t_s)
    )
    return aim @ turn


def test_two_head_mounted_sensors_capture_each_others_wearer_where_the_truth_is() -> None:
    hub = FusionHub(
        HubSettings(),
        Calibration(1, 0.0, {}, spaces={"room": SpaceCalibration(WORLD_FROM_SPACE, "manual")}),
    )
    for k in (0, 1):
        hub.handle_message(bytes([k]), [moving_hello(f"head-{k}")], T0, 0.0)
    fused = []
    for i in range(60):
        t = i / FPS
        for k in (0, 1):
            pose = head_sensor(k, t)
            frame = Frame(
                i + 1,
                round((T0 + t) * 1e9),
                (body(100 + k, seen(pose, wearer_truth(1 - k, t))),),
                None,
                space_pose(pose),
            )
            hub.handle_message(bytes([k]), [encode(frame)], T0 + t + 0.004, t + 0.004)
        out = hub.fuse_step(T0 + t + 0.005)
        if out is not None:
            fused.append(out)
    assert len(fused) > 40
    for out in fused[-20:]:
        t = out.t_s - T0
        assert len(out.persons) == 2
        for person in out.persons:
            (view,) = person.views  # each wearer is seen by the other's sensor only
            wearer = 1 - int(view.sensor_id[-1])
            truth = wearer_truth(wearer, t)
            error = np.linalg.norm(person.joints - truth, axis=1)
            assert np.nanmedian(error) < 0.02, (out.t_s, view.sensor_id, np.nanmedian(error))
            # The view looks from where the sensor is at that instant, in the world.
            sensor_at = head_sensor(1 - wearer, t)[:3, 3]
            assert view.sensor_position is not None
            np.testing.assert_allclose(view.sensor_position, sensor_at, atol=0.01)


def test_views_at_places_a_moving_sensor_with_its_space_and_its_position() -> None:
    hub = FusionHub(HubSettings())
    hub.handle_message(b"a", [moving_hello("head-a")], T0, 0.0)
    for i, t in enumerate((0.0, 0.1)):
        pose = head_sensor(0, t)
        frame = Frame(
            i + 1, round((T0 + t) * 1e9), (body(5, seen(pose, wearer_truth(1, t))),), None,
            space_pose(pose),
        )  # fmt: skip
        hub.handle_message(b"a", [encode(frame)], T0 + t + 0.004, t)
    sensor = hub.sensors["head-a"]
    (view,) = views_at([sensor], lambda _: WORLD_FROM_SPACE, T0 + 0.054, 0.2)  # offset 4 ms
    # Bodies interpolated in the space: the midpoint of the two truths (linear walking).
    np.testing.assert_allclose(view.joints_world, wearer_truth(1, 0.05), atol=1e-5)
    midway = (head_sensor(0, 0.0)[:3, 3] + head_sensor(0, 0.1)[:3, 3]) / 2
    assert view.sensor_position is not None
    np.testing.assert_allclose(view.sensor_position, midway, atol=1e-6)


def test_a_late_moving_sensor_looks_from_where_its_newest_frame_put_it() -> None:
    # The deadline alignment carries a late sensor's bodies forward; its position too must be
    # the sensor's in the world, not its space's origin.
    hub = FusionHub(HubSettings())
    hub.handle_message(b"a", [moving_hello("head-a")], T0, 0.0)
    for i, t in enumerate((0.0, 1 / FPS)):
        pose = head_sensor(0, t)
        frame = Frame(
            i + 1, round((T0 + t) * 1e9), (body(5, seen(pose, wearer_truth(1, t))),), None,
            space_pose(pose),
        )  # fmt: skip
        hub.handle_message(b"a", [encode(frame)], T0 + t + 0.004, t)
    sensor = hub.sensors["head-a"]
    t_s = sensor.frames[-1].t_server_s + 0.01
    (view,) = views_with_late([sensor], lambda _: WORLD_FROM_SPACE, t_s, 0.2, {"head-a": 0.01}, ())
    assert view.sensor_position is not None
    np.testing.assert_allclose(view.sensor_position, head_sensor(0, 1 / FPS)[:3, 3], atol=1e-6)
