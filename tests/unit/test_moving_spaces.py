"""Separate tracking spaces (issue 15): each head-mounted sensor in its own space, as two headsets
without a shared anchor are, each space with its own ``T_world_from_space``. Stored, they fuse
as one shared space does; unknown, a skeleton calibration run (the existing body-based path, its
reference's space taken as the world) solves them and its commit stores them. Fake clock, real
hub, as tests/unit/test_moving_calibration.py."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.store import Calibration, SpaceCalibration
from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.settings import HubSettings
from skelfuse.protocol.sensor_pose import pose_from_matrix
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import (
    Matrix4,
    apply,
    invert,
    look_at_pose,
    pose_from_position_yaw_pitch,
)
from skelfuse.protocol.wire import Body, Frame, Hello, encode
from skelfuse.server.calibration_run import RunSpec, RunState
from skelfuse.server.hub import FusionHub
from tests.unit.test_calibration_runs import PERFORMER, START_S, Rig, finished, floor_plane

HEADS = ("head-0", "head-1")
# Each headset's own tracking space, turned and shifted differently against the world.
WORLD_FROM_SPACE = {
    "quest-0": pose_from_position_yaw_pitch((1.0, 0.0, 0.0), 30.0),
    "quest-1": pose_from_position_yaw_pitch((-0.5, 0.0, 1.0), -60.0),
}
PER_WEARER = {"head-0": "quest-0", "head-1": "quest-1"}
ONE_SPACE = {"head-0": "room", "head-1": "room"}


def head_pose(sensor_id: str, t_s: float) -> Matrix4:
    """Each wearer's head-mounted sensor in the world, looking at the room's middle and turning
    ±15° in yaw (out of step)."""
    k = HEADS.index(sensor_id)
    eye = ((-2.0, 1.7, 1.5), (2.2, 1.6, 1.8))[k]
    aim = look_at_pose(eye, (0.0, 1.0, 0.0))
    return aim @ pose_from_position_yaw_pitch((0.0, 0.0, 0.0), 15.0 * math.sin(3.0 * t_s + k))


def walker(t_s: float) -> npt.NDArray[np.float64]:
    """The walking performer both sensors look at (world joints (25, 3))."""
    return PERFORMER.joints_at((t_s - START_S) % 6.3)[0]


def frame_of(
    sensor_id: str, seq: int, t_s: float, space_of: dict[str, str], world: dict[str, Matrix4]
) -> Frame:
    """``sensor_id``'s frame at ``t_s``: the walker in its camera frame, its Kinect floor plane,
    and its pose in its own space (``T_space_from_sensor``)."""
    pose = head_pose(sensor_id, t_s - START_S)
    states = np.full(JOINT_COUNT, TrackingState.TRACKED, np.uint8)
    body = Body(7, apply(invert(pose), walker(t_s)).astype(np.float32), states)
    in_space = pose_from_matrix(invert(world[space_of[sensor_id]]) @ pose)
    return Frame(seq, round(t_s * 1e9), (body,), floor_plane(pose), in_space)


def hello(sensor_id: str, space_of: dict[str, str]) -> bytes:
    return encode(
        Hello(sensor_id, "sim", "t", 30.0, 0, moving=True, pose_space=space_of[sensor_id])
    )


def fused_run(space_of: dict[str, str], world: dict[str, Matrix4]) -> list[FusedFrame]:
    """Two seconds of both sensors fused by a hub that has ``world`` stored for their spaces."""
    spaces = {s: SpaceCalibration(world[s], "manual") for s in set(space_of.values())}
    hub = FusionHub(HubSettings(), Calibration(1, 0.0, {}, spaces=spaces))
    for i, sensor_id in enumerate(HEADS):
        hub.handle_message(bytes([i]), [hello(sensor_id, space_of)], START_S, 0.0)
    out = []
    for n in range(60):
        t = START_S + n / 30
        for i, sensor_id in enumerate(HEADS):
            frame = frame_of(sensor_id, n + 1, t, space_of, world)
            hub.handle_message(bytes([i]), [encode(frame)], t + 0.004, n / 30)
        fused = hub.fuse_step(t + 0.005)
        if fused is not None:
            out.append(fused)
    return out


def test_each_wearer_in_its_own_stored_space_fuses_as_one_shared_space() -> None:
    separate = fused_run(PER_WEARER, WORLD_FROM_SPACE)
    shared = fused_run(ONE_SPACE, {"room": np.eye(4)})
    assert len(separate) == len(shared) > 40
    for mine, theirs in zip(separate[-20:], shared[-20:], strict=True):
        (person,), (same,) = mine.persons, theirs.persons
        assert {v.sensor_id for v in person.views} == set(HEADS)  # one person, both views
        error = np.linalg.norm(person.joints - walker(mine.t_s), axis=1)
        assert np.nanmedian(error) < 0.02, np.nanmedian(error)
        # Only rounding tells them apart (float32 joints placed through another transform).
        np.testing.assert_allclose(person.joints, same.joints, atol=1e-4)
        for view in person.views:
            assert view.sensor_position is not None
            expected = head_pose(view.sensor_id, mine.t_s - START_S)[:3, 3]
            np.testing.assert_allclose(view.sensor_position, expected, atol=0.01)


class SpacesRig(Rig):
    """``head-0`` and ``head-1`` moving, each in its own space, no fixed sensor."""

    def __init__(self, tmp_path: Path) -> None:
        super().__init__(tmp_path, ())
        self.sensors = HEADS
        for i, sensor_id in enumerate(HEADS):
            message = hello(sensor_id, PER_WEARER)
            self.hub.handle_message(bytes([i]), [message], self.clock.wall, self.clock.mono)

    def stream(self) -> None:
        while self.next_frame_s <= self.clock.wall:
            t = self.next_frame_s
            self.seq += 1
            for i, sensor_id in enumerate(self.sensors):
                frame = frame_of(sensor_id, self.seq, t, PER_WEARER, WORLD_FROM_SPACE)
                self.hub.handle_message(bytes([i]), [encode(frame)], t, self.clock.mono)
            self.next_frame_s += 1 / 30


async def test_a_skeleton_run_solves_every_wearers_space_from_the_references(
    tmp_path: Path,
) -> None:
    rig = SpacesRig(tmp_path)
    # Two spaces and nothing stored: neither is the world (the floor rule needs a lone space).
    for sensor_id in HEADS:
        assert rig.hub.pose_of(sensor_id) == (None, "uncalibrated")
    service = rig.service()
    run = await finished(service.start(RunSpec("skeleton", "head-0", HEADS, duration_s=4.0)))
    assert run.state == RunState.DONE, run.error
    committed = await service.commit(run.run_id)
    assert committed.sensors == {} and set(committed.spaces) == set(WORLD_FROM_SPACE)
    solved = {s: c.T_world_from_space for s, c in committed.spaces.items()}
    # The run's world is its reference's space, levelled on its floor: only the spaces'
    # relative pose is the truth's.
    relative = invert(solved["quest-0"]) @ solved["quest-1"]
    truth = invert(WORLD_FROM_SPACE["quest-0"]) @ WORLD_FROM_SPACE["quest-1"]
    rotation_deg, translation_mm = pose_error(relative, truth)
    assert rotation_deg < 0.5 and translation_mm < 10.0, (rotation_deg, translation_mm)
    level = solved["quest-0"][:3, :3] @ invert(WORLD_FROM_SPACE["quest-0"])[:3, :3]
    assert abs(level[1, 1] - 1.0) < 1e-4  # the same up: the world differs by a yaw and a shift
    for sensor_id in HEADS:
        pose, source = rig.hub.pose_of(sensor_id)
        assert source == "stored" and pose is solved[PER_WEARER[sensor_id]]
    # Fused with the solved spaces: where the walker is, once the run's world is moved onto
    # the truth's (the gauge the reference's space fixes).
    gauge = WORLD_FROM_SPACE["quest-0"] @ invert(solved["quest-0"])
    fused = []
    for _ in range(30):  # a second of live fusion: a new track shows after a few frames
        await rig.clock.sleep(1 / 30)
        out = rig.hub.fuse_step(rig.clock.wall)
        fused.extend([out] if out is not None and out.persons else [])
    assert len(fused) > 20
    for out in fused[-10:]:
        (person,) = out.persons
        error = np.linalg.norm(apply(gauge, person.joints) - walker(out.t_s), axis=1)
        assert np.nanmedian(error) < 0.03, np.nanmedian(error)
