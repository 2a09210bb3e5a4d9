"""Calibrating a tracking space with the existing methods: a skeleton run over a fixed sensor and
a head-mounted one (its head turning) solves the moving sensor's bodies, already placed in its
space, for ``T_world_from_space``; the commit stores it as the space's transform, which every
sensor of the space then shares. Fake clock, real hub, as tests/unit/test_calibration_runs.py."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.store import (
    CalibrationFileError,
    CalibrationStore,
    SensorCalibration,
    SpaceCalibration,
)
from skelfuse.protocol.depth_cloud import encode_reply
from skelfuse.protocol.sensor_pose import pose_from_matrix
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import apply, invert, look_at_pose, pose_from_position_yaw_pitch
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.calibration_run import RunSpec, RunState
from skelfuse.server.depth_clouds import capture_clouds
from skelfuse.server.errors import AgentRequestFailed
from tests.unit.test_calibration_runs import (
    PERFORMER,
    POSES,
    START_S,
    FakeAgents,
    Rig,
    finished,
    floor_plane,
)

WORLD_FROM_SPACE = pose_from_position_yaw_pitch((0.5, 0.0, -1.0), -40.0)


def head_pose(t_s: float) -> np.ndarray:
    """The head-mounted sensor in the world: 2.5 m from the room's middle, turning ±15° in
    yaw."""
    aim = look_at_pose((-2.0, 1.7, 1.5), (0.0, 1.0, 0.0))
    return aim @ pose_from_position_yaw_pitch((0.0, 0.0, 0.0), 15.0 * math.sin(3.0 * t_s))


class MovingRig(Rig):
    """``cam-a`` fixed and ``head-b`` moving in tracking space ``room``."""

    def __init__(self, tmp_path: Path) -> None:
        super().__init__(tmp_path, ("cam-a",))
        self.sensors = ("cam-a", "head-b")
        hello = Hello("head-b", "sim", "t", 30.0, 0, moving=True, pose_space="room")
        self.hub.handle_message(b"\x01", [encode(hello)], self.clock.wall, self.clock.mono)

    def stream(self) -> None:
        while self.next_frame_s <= self.clock.wall:
            t = self.next_frame_s
            world = PERFORMER.joints_at((t - START_S) % 6.3)[0]
            self.seq += 1
            states = np.full(JOINT_COUNT, TrackingState.TRACKED, np.uint8)
            for i, sensor_id in enumerate(self.sensors):
                moving = sensor_id == "head-b"
                pose = head_pose(t - START_S) if moving else POSES[sensor_id]
                body = Body(7 + i, apply(invert(pose), world).astype(np.float32), states)
                space_pose = pose_from_matrix(invert(WORLD_FROM_SPACE) @ pose) if moving else None
                frame = Frame(self.seq, round(t * 1e9), (body,), floor_plane(pose), space_pose)
                self.hub.handle_message(bytes([i]), [encode(frame)], t, self.clock.mono)
            self.next_frame_s += 1 / 30


async def test_a_skeleton_run_calibrates_the_moving_sensors_space(tmp_path: Path) -> None:
    rig = MovingRig(tmp_path)
    # A fixed sensor without a pose is no frame of reference: the space is taken as the world.
    assert rig.hub.pose_of("head-b")[1] == "floor"
    service = rig.service()
    run = await finished(service.start(RunSpec("skeleton", "cam-a", rig.sensors, duration_s=4.0)))
    assert run.state == RunState.DONE, run.error
    solved = invert(run.results["cam-a"].T_world_from_sensor)
    solved = solved @ run.results["head-b"].T_world_from_sensor
    truth = invert(POSES["cam-a"]) @ WORLD_FROM_SPACE
    rotation_deg, translation_mm = pose_error(solved, truth)
    assert rotation_deg < 0.5 and translation_mm < 10.0, (rotation_deg, translation_mm)
    committed = await service.commit(run.run_id)
    assert set(committed.sensors) == {"cam-a"} and set(committed.spaces) == {"room"}
    assert committed.spaces["room"].details["sensor"] == "head-b"
    stored = CalibrationStore(tmp_path).load()
    assert stored is not None and set(stored.spaces) == {"room"}
    pose, source = rig.hub.pose_of("head-b")
    assert source == "stored" and pose is not None
    np.testing.assert_array_equal(pose, committed.spaces["room"].T_world_from_space)


def test_the_store_keeps_tracking_spaces_and_reads_files_from_before_them(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path)
    fixed = {"cam-a": SensorCalibration(POSES["cam-a"], "points")}
    plain = store.save(fixed)
    assert "spaces" not in json.loads(store.path.read_text())  # as before spaces existed
    assert plain.spaces == {}
    room = {"room": SpaceCalibration(WORLD_FROM_SPACE, "manual", 3.0, {"by": "hand"})}
    with_space = store.save(fixed, note="space", spaces=room)
    loaded = store.load()
    assert loaded is not None and loaded.version == with_space.version
    np.testing.assert_array_equal(loaded.spaces["room"].T_world_from_space, WORLD_FROM_SPACE)
    assert (loaded.spaces["room"].method, loaded.spaces["room"].residual_mm) == ("manual", 3.0)
    # A save that only knows sensors keeps the spaces; a rollback restores that version's.
    assert set(store.save({}, note="sensors only").spaces) == {"room"}
    assert store.rollback(plain.version).spaces == {}
    assert set(store.rollback(with_space.version).spaces) == {"room"}
    exported = with_space.to_json()
    assert set(store.import_json(exported).spaces) == {"room"}
    exported["spaces"]["room"]["T_world_from_space"][0][0] = 2.0
    with pytest.raises(CalibrationFileError, match=r"space 'room'.*not a rigid"):
        store.import_json(exported)
    with pytest.raises(CalibrationFileError, match="'spaces' must be an object"):
        store.import_json({**exported, "spaces": [1]})


async def test_a_moving_sensors_depth_cloud_is_placed_in_its_space_for_icp(tmp_path: Path) -> None:
    rig = MovingRig(tmp_path)
    await rig.clock.sleep(0.3)  # frames of both sensors
    rng = np.random.default_rng(4)
    room = rng.uniform(-3.0, 3.0, (800, 3))  # points in the world
    head = rig.hub.sensors["head-b"]
    t_s = head.frames[-1].t_server_s - 0.02  # between its two newest frames
    pose = head_pose(t_s - START_S)
    captured_ns = round((t_s - (head.clock_offset_s or 0.0)) * 1e9)

    def answer(sensor_id: str) -> object:
        sensor_pose = pose if sensor_id == "head-b" else POSES[sensor_id]
        return encode_reply(apply(invert(sensor_pose), room), t_capture_ns=captured_ns)

    clouds = await capture_clouds(FakeAgents(answer), ("cam-a", "head-b"), rig.hub.sensors)
    # cam-a's stays in its frame; head-b's is in its space, where its bodies are.
    np.testing.assert_allclose(apply(POSES["cam-a"], clouds["cam-a"]), room, atol=1e-5)
    np.testing.assert_allclose(apply(WORLD_FROM_SPACE, clouds["head-b"]), room, atol=2e-3)
    late = encode_reply(room, t_capture_ns=captured_ns + 3 * 10**9)  # no frame says where
    with pytest.raises(AgentRequestFailed, match=r"'head-b'.*no frame says where"):
        await capture_clouds(FakeAgents(lambda _: late), ("head-b",), rig.hub.sensors)
