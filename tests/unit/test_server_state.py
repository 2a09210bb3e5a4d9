"""Server state without sockets: clock offsets, alignment, the hub's message handling, the
calibration store and the CLI's argument parsing."""

from __future__ import annotations

import json
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.store import CalibrationFileError, CalibrationStore, SensorCalibration
from skelfuse.cli.values import UsageError, parse_host_port, parse_pose
from skelfuse.fusion.sensors import SlidingMinimum, TimedFrame, bodies_at
from skelfuse.protocol.depth_cloud import decode_reply
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.feed import frame_json
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.transform import pose_from_position_yaw_pitch
from skelfuse.protocol.wire import Body, ErrorMessage, Frame, Heartbeat, Hello, Welcome, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings

STATES = np.full(JOINT_COUNT, 2, np.uint8)


def body(tracking_id: int, value: float) -> Body:
    return Body(tracking_id, np.full((JOINT_COUNT, 3), value, np.float32), STATES.copy())


def timed(t: float, *bodies: Body) -> TimedFrame:
    return TimedFrame(t, Frame(int(t * 1000), int(t * 1e9), bodies))


# --- clock and alignment --------------------------------------------------------------------


def test_sliding_minimum_follows_the_window() -> None:
    window = SlidingMinimum(10.0)
    assert window.push(0.0, 5.0) == 5.0
    assert window.push(1.0, 3.0) == 3.0
    assert window.push(2.0, 4.0) == 3.0
    assert window.push(11.5, 6.0) == 4.0  # the 3.0 from t=1 has left the window
    assert window.push(13.0, 7.0) == 6.0


def test_bodies_at_interpolates_between_frames() -> None:
    frames = deque([timed(1.0, body(7, 0.0)), timed(1.1, body(7, 1.0))])
    (result,) = bodies_at(frames, 1.025, max_gap_s=0.2, max_age_s=0.05) or ()
    np.testing.assert_allclose(result.joints_m, 0.25, atol=1e-6)


def test_bodies_at_takes_lower_state_and_nearer_for_missing() -> None:
    first, second = body(7, 0.0), body(7, 1.0)
    first.states[3] = 1
    second.joints_m[4] = np.nan
    second.states[4] = 0
    (result,) = bodies_at(deque([timed(1.0, first), timed(1.1, second)]), 1.08, 0.2, 0.05) or ()
    assert result.states[3] == 1
    assert np.isnan(result.joints_m[4]).all() and result.states[4] == 0


def test_bodies_at_uses_nearest_when_frames_are_far_apart() -> None:
    frames = deque([timed(1.0, body(7, 0.0)), timed(2.0, body(7, 1.0))])
    (result,) = bodies_at(frames, 1.02, max_gap_s=0.1, max_age_s=0.05) or ()
    np.testing.assert_allclose(result.joints_m, 0.0)
    assert bodies_at(frames, 1.5, max_gap_s=0.1, max_age_s=0.05) is None


def test_bodies_at_does_not_extrapolate_stale_frames() -> None:
    frames = deque([timed(1.0, body(7, 0.0))])
    assert bodies_at(frames, 1.03, 0.1, 0.05) is not None
    assert bodies_at(frames, 1.2, 0.1, 0.05) is None
    assert bodies_at(deque(), 1.0, 0.1, 0.05) is None


def test_body_only_in_one_frame_comes_from_the_nearer_frame() -> None:
    frames = deque([timed(1.0, body(7, 0.0)), timed(1.1, body(7, 1.0), body(9, 5.0))])
    result = bodies_at(frames, 1.09, 0.2, 0.05) or ()
    assert sorted(b.tracking_id for b in result) == [7, 9]
    result = bodies_at(frames, 1.01, 0.2, 0.05) or ()
    assert [b.tracking_id for b in result] == [7]


# --- hub ------------------------------------------------------------------------------------


def hello(sensor_id: str = "cam", hint: bool = True) -> bytes:
    pose = pose_from_position_yaw_pitch((0.0, 1.0, 3.0), 180.0) if hint else None
    return encode(Hello(sensor_id, "sim", "t", 30.0, 0, pose_hint=pose,
                        pose_hint_source="sim_truth" if hint else None))  # fmt: skip


def test_hub_registers_then_accepts_frames_and_estimates_offset() -> None:
    hub = FusionHub(Settings())
    (reply,) = hub.handle_message(b"r1", [hello()], 100.0, 10.0)
    assert isinstance(reply, Welcome)
    agent_clock_ns = int((100.0 - 5.0) * 1e9)  # this agent's clock is 5 s behind
    for i in range(3):
        frame = Frame(i + 1, agent_clock_ns + i * 33_000_000, (body(1, 0.5),))
        assert hub.handle_message(b"r1", [encode(frame)], 100.001 + i * 0.033, 10.0) == []
    sensor = hub.sensors["cam"]
    assert sensor.clock_offset_s == pytest.approx(5.001, abs=1e-3)
    assert sensor.frames_received == 3 and sensor.sequence_gaps == 0
    assert hub.pose_of("cam")[1] == "sim_truth"


def test_hub_refuses_frames_from_strangers_and_counts_garbage() -> None:
    hub = FusionHub(Settings())
    (reply,) = hub.handle_message(b"x", [encode(Heartbeat(1))], 0.0, 0.0)
    assert isinstance(reply, ErrorMessage) and reply.code == "not_registered"
    hub.handle_message(b"x", [b"garbage"], 0.0, 0.0)
    assert hub.rejected_unregistered == {"not_registered": 1, "malformed": 1}
    hub.handle_message(b"r", [hello()], 0.0, 0.0)
    hub.handle_message(b"r", [b"\x93"], 0.0, 0.0)
    hub.handle_message(b"r", [encode(Frame(5, 1, ()))], 0.0, 0.0)
    hub.handle_message(b"r", [encode(Frame(5, 2, ()))], 0.0, 0.0)
    hub.handle_message(b"r", [encode(Frame(9, 3, ()))], 0.0, 0.0)
    sensor = hub.sensors["cam"]
    assert dict(sensor.frames_rejected) == {"malformed": 1, "replayed_seq": 1}
    assert sensor.sequence_gaps == 3


def test_hub_liveness_and_bye() -> None:
    hub = FusionHub(Settings(heartbeat_interval_s=1.0))
    hub.handle_message(b"a", [hello("a")], 0.0, 0.0)
    hub.handle_message(b"b", [hello("b")], 0.0, 0.0)
    assert {s.sensor_id for s in hub.check_liveness(2.7)} == {"a", "b"}
    hub.handle_message(b"a", [encode(Heartbeat(1))], 0.0, 2.7)
    assert {s.sensor_id for s in hub.check_liveness(3.5)} == {"a"}
    from skelfuse.protocol.wire import Bye

    hub.handle_message(b"a", [encode(Bye())], 0.0, 3.6)
    assert hub.check_liveness(3.7) == []


def test_stored_calibration_wins_over_pose_hint(tmp_path: Path) -> None:
    stored = pose_from_position_yaw_pitch((1.0, 2.0, 3.0), 45.0)
    calibration = CalibrationStore(tmp_path).save({"cam": SensorCalibration(stored, "points")})
    hub = FusionHub(Settings(), calibration)
    hub.handle_message(b"r", [hello()], 0.0, 0.0)
    pose, state = hub.pose_of("cam")
    assert state == "stored" and pose is not None
    np.testing.assert_allclose(pose, stored)
    assert hub.pose_of("unknown") == (None, "uncalibrated")


def test_fuse_step_outputs_json_without_nan() -> None:
    hub = FusionHub(Settings())
    now = 1_763_712_345.0
    hub.handle_message(b"r", [hello()], now, 0.0)
    joints = np.zeros((JOINT_COUNT, 3), np.float32) + [0.0, 0.0, 2.5]
    states = STATES.copy()
    joints[4], states[4] = np.nan, 0
    for i in range(5):
        frame = Frame(i + 1, int((now + i / 30) * 1e9), (Body(1, joints, states),))
        hub.handle_message(b"r", [encode(frame)], now + i / 30, i / 30)
        fused = hub.fuse_step(now + i / 30)
    assert fused is not None and len(fused.persons) == 1
    text = json.dumps(frame_json(fused, include_raw=True), allow_nan=False)
    message = json.loads(text)
    assert message["persons"][0]["joints"][4] is None
    assert message["persons"][0]["confidence"][4] == 0.0
    assert message["raw"][0]["tracking_id"] == "1"
    assert hub.fuse_step(now + 4 / 30) is None, "nothing new to fuse"


# --- calibration store ------------------------------------------------------------------------


def test_store_round_trip_versions_and_history(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path / "data")
    assert store.load() is None
    pose = pose_from_position_yaw_pitch((0.5, 1.2, -2.0), 30.0, 10.0)
    first = store.save({"a": SensorCalibration(pose, "points", 3.5)})
    second = store.save({"a": SensorCalibration(np.eye(4), "icp")})
    assert (first.version, second.version) == (1, 2)
    loaded = store.load()
    assert loaded is not None and loaded.version == 2
    np.testing.assert_allclose(loaded.sensors["a"].T_world_from_sensor, np.eye(4))
    assert (tmp_path / "data" / "calibration-history" / "v000001.json").is_file()
    leftovers = [p.name for p in (tmp_path / "data").iterdir() if p.name.startswith(".")]
    assert leftovers == [], "no temporary files may be left behind"


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "not valid JSON"),
        ('{"format": 99}', "format 1"),
        ('{"format": 1, "sensors": {"a": {"T_world_from_sensor": [[2,0,0,0],[0,1,0,0],'
         '[0,0,1,0],[0,0,0,1]]}}}', "not a rigid"),
    ],
)  # fmt: skip
def test_store_refuses_bad_files_with_a_clear_error(
    tmp_path: Path, content: str, message: str
) -> None:
    (tmp_path / "calibration.json").write_text(content)
    with pytest.raises(CalibrationFileError, match=message):
        CalibrationStore(tmp_path).load()


# --- CLI parsing ----------------------------------------------------------------------------


def test_parse_pose() -> None:
    assert parse_pose("-2,1,3,90") == ((-2.0, 1.0, 3.0), 90.0, 0.0)
    assert parse_pose("0,1.5,2,180,10") == ((0.0, 1.5, 2.0), 180.0, 10.0)
    for bad in ("1,2,3", "a,b,c,d", "0,1,2,3,95", "0,1,nan,3"):
        with pytest.raises(UsageError):
            parse_pose(bad)


def test_parse_host_port() -> None:
    assert parse_host_port("0.0.0.0:9000", 8000) == ("0.0.0.0", 9000)
    assert parse_host_port("[::1]:9000", 8000) == ("::1", 9000)
    assert parse_host_port("myhost", 8000) == ("myhost", 8000)
    with pytest.raises(UsageError):
        parse_host_port("h:99999", 8000)


# --- requests to agents ---------------------------------------------------------------------


def test_large_response_only_when_the_server_is_waiting() -> None:
    from skelfuse.protocol.constants import MAX_MESSAGE_BYTES, MAX_RESPONSE_BYTES
    from skelfuse.protocol.errors import DecodeError
    from skelfuse.protocol.wire import Response, decode

    cloud = Response(1, ok=True, result={"points": b"\0" * (300 * 1024)})
    payload = encode(cloud)
    with pytest.raises(DecodeError) as info:
        decode(payload)
    assert info.value.reason == "too_large"
    assert decode(payload, MAX_RESPONSE_BYTES) == cloud
    import msgpack

    padded_frame = msgpack.packb(
        {
            "v": 1,
            "type": "frame",
            "seq": 1,
            "t_capture_ns": 1,
            "bodies": [],
            "pad": b"\0" * (2 * MAX_MESSAGE_BYTES),
        }
    )
    with pytest.raises(DecodeError) as info:  # other types never get the larger limit
        decode(padded_frame, MAX_RESPONSE_BYTES)
    assert info.value.reason == "too_large"


def test_sim_agent_answers_depth_cloud_in_its_own_frame() -> None:
    from skelfuse.agent.sim.performer import ProceduralPerformer
    from skelfuse.agent.sources.sim import SimSource
    from skelfuse.protocol.transform import apply as apply_pose

    pose = pose_from_position_yaw_pitch((0.0, 1.2, 3.0), 180.0, 10.0)
    source = SimSource(ProceduralPerformer(1), pose, seed=2)
    result = source.request_handlers()["depth_cloud"]({"max_points": 8000})
    points = decode_reply(result)
    assert result["count"] == len(points) <= 8000
    assert len(points) > 2000
    world = apply_pose(pose, points)
    # The floor is there: a good share of points lies at y ≈ 0 in the world.
    assert np.mean(np.abs(world[:, 1]) < 0.03) > 0.15
    # The request is read by the protocol's codec, as every source does (a refusal to the server).
    with pytest.raises(DecodeError, match="max_points"):
        source.depth_cloud({"max_points": 0})


# --- clocks ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("delay_s", "drift", "tolerance_s"),
    [
        (0.0005, 30e-6, 0.0005),  # wired LAN, a typical PC clock
        (0.0005, 300e-6, 0.001),  # wired LAN, a bad clock
        (0.002, 300e-6, 0.003),  # jittery Wi-Fi, a bad clock
    ],
)
def test_round_trip_offset_follows_offset_and_drift(
    delay_s: float, drift: float, tolerance_s: float
) -> None:
    from skelfuse.fusion.sensors import RoundTripOffset

    rng = np.random.default_rng(5)
    estimator = RoundTripOffset()
    offset0 = -4.2  # agent clock 4.2 s ahead, and running fast by `drift`
    errors = []
    for i in range(240):  # two minutes of heartbeats every 0.5 s
        sent = 1000.0 + i * 0.5
        up, down = rng.exponential(delay_s, 2) + 0.0002  # one-way delays, asymmetric
        agent_time = (sent + up) - (offset0 - drift * (sent + up - 1000.0))
        estimator.add(sent, agent_time, sent + up + down)
        true_offset = offset0 - drift * (sent + up - 1000.0)
        errors.append(abs(estimator.offset_s - true_offset))  # type: ignore[operator]
    assert max(errors[20:]) < tolerance_s
    assert estimator.rtt_s is not None and estimator.rtt_s < 4 * delay_s


def test_round_trip_offset_recovers_from_a_clock_step() -> None:
    from skelfuse.fusion.sensors import RoundTripOffset

    estimator = RoundTripOffset()
    for i in range(20):
        estimator.add(i * 0.5, i * 0.5 - 2.0 + 0.0005, i * 0.5 + 0.001)
    assert estimator.offset_s == pytest.approx(2.0, abs=1e-3)
    for i in range(20, 26):  # the agent's clock jumps 1 s forward
        estimator.add(i * 0.5, i * 0.5 - 1.0 + 0.0005, i * 0.5 + 0.003)
    assert estimator.offset_s == pytest.approx(1.0, abs=2e-3)


def test_stale_and_future_frames_are_rejected() -> None:
    hub = FusionHub(Settings())
    hub.handle_message(b"r", [hello()], 100.0, 0.0)
    hub.handle_message(b"r", [encode(Heartbeat(int(100.0e9), echo_ns=int(99.999e9)))], 100.0, 0.0)
    sensor = hub.sensors["cam"]
    assert sensor.round_trip.offset_s == pytest.approx(0.0, abs=1e-3)
    fresh = Frame(1, int(100.0e9), (body(1, 0.5),))
    backlog = Frame(2, int(98.0e9), (body(1, 0.5),))  # captured 2 s ago
    jumped = Frame(3, int(160.0e9), (body(1, 0.5),))  # a minute in the future
    for frame in (fresh, backlog, jumped):
        hub.handle_message(b"r", [encode(frame)], 100.01, 0.0)
    assert dict(sensor.frames_rejected) == {"stale": 1, "future": 1}
    assert sensor.frames_received == 1
    assert sensor.clock_source == "round_trip"
