"""The server's skeleton calibration runs fit a pair with an ``rgb`` (mono) sensor with the rgb
RANSAC settings (calibration/skeleton_pose.py RGB_*; picked by the sensors' registered types),
and keep the depth sensors' defaults otherwise: whole runs through CalibrationService with the
fake clock and a real hub (tests/unit/test_calibration_runs.py's rig), the frames carrying a mono
source's depth errors (test_skeleton_mono.py's: the body slides along each camera's rays by
8 % per frame, and by a size bias of +-5 % for good)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skelfuse.calibration.body_pairing import DEPTH_MIN_SCALE_M, DEPTH_RANSAC_THRESHOLD_M
from skelfuse.calibration.rigid import pose_error
from skelfuse.calibration.skeleton_pose import RGB_MIN_SCALE_M, RGB_RANSAC_THRESHOLD_M
from skelfuse.calibration.store import SensorCalibration
from skelfuse.protocol.skeleton import JOINT_COUNT, JointId, TrackingState
from skelfuse.protocol.transform import apply, invert
from skelfuse.protocol.wire import Body, Frame, encode
from skelfuse.server.calibration_run import CalibrationRun, RunSpec, RunState
from tests.unit.test_calibration_runs import (
    PERFORMER,
    POSES,
    START_S,
    Rig,
    bumped,
    finished,
    relative,
)

WALK_S = 20.0
RGB = (RGB_RANSAC_THRESHOLD_M, RGB_MIN_SCALE_M)
DEPTH = (DEPTH_RANSAC_THRESHOLD_M, DEPTH_MIN_SCALE_M)


class MonoRig(Rig):
    """The rig's sensors registered with ``types`` and seen as a mono source sees: depth scaled
    per frame along the camera's rays (sd 8 %) and by a size bias per sensor (+5 %, -5 %);
    SpineMid and Neck Inferred (synthesised by the mono mapping)."""

    def __init__(self, tmp_path: Path, types: dict[str, str]) -> None:
        self.rng = np.random.default_rng(0)
        self.bias = {"cam-a": 0.05, "cam-b": -0.05}
        super().__init__(tmp_path)
        for sensor_id, kind in types.items():
            self.hub.sensors[sensor_id].sensor_type = kind

    def stream(self) -> None:
        while self.next_frame_s <= self.clock.wall:
            t = self.next_frame_s
            world = PERFORMER.joints_at(2.0 + (t - START_S) % 18.0)[0]
            self.seq += 1
            for i, sensor_id in enumerate(self.sensors):
                scale = 1.0 + self.bias[sensor_id] + self.rng.normal(0.0, 0.08)
                joints = apply(invert(POSES[sensor_id]), world) * scale
                joints += self.rng.normal(0.0, 0.01, joints.shape)
                states = np.full(JOINT_COUNT, TrackingState.TRACKED, np.uint8)
                states[[JointId.SPINE_MID, JointId.NECK]] = TrackingState.INFERRED
                body = Body(7 + i, joints.astype(np.float32), states)
                frame = Frame(self.seq, round(t * 1e9), (body,))
                self.hub.handle_message(bytes([i]), [encode(frame)], t, self.clock.mono)
            self.next_frame_s += 1 / 30


async def skeleton_run(rig: Rig) -> CalibrationRun:
    spec = RunSpec("skeleton", "cam-a", ("cam-a", "cam-b"), duration_s=WALK_S)
    return await finished(rig.service().start(spec))


def settings_of(run: CalibrationRun, sensor_id: str) -> tuple[float, float]:
    metrics = run.results[sensor_id].metrics
    return metrics["ransac_threshold_m"], metrics["min_scale_m"]


def rotation_error_deg(run: CalibrationRun) -> float:
    truth = invert(POSES["cam-a"]) @ POSES["cam-b"]
    return pose_error(relative(run.results, "cam-a", "cam-b"), truth)[0]


async def test_a_run_with_an_rgb_sensor_uses_the_rgb_settings(tmp_path: Path) -> None:
    """The types decide: the same frames from two rgb sensors, from an rgb and a sim sensor,
    and from two sim sensors; the rgb settings keep 280 of the frames and land 0.3 deg / 112 mm
    off, the Kinect's keep 109 and land 1.9 deg / 130 mm off (what the rgb settings are for)."""
    runs = {}
    for name, types in (
        ("rgb", {"cam-a": "rgb", "cam-b": "rgb"}),
        ("mixed", {"cam-b": "rgb"}),
        ("sim", {}),
    ):
        run = await skeleton_run(MonoRig(tmp_path / name, types))
        assert run.state == RunState.DONE, run.error
        runs[name] = run
    assert settings_of(runs["rgb"], "cam-b") == settings_of(runs["mixed"], "cam-b") == RGB
    assert settings_of(runs["sim"], "cam-b") == DEPTH
    for name in ("rgb", "mixed"):
        assert rotation_error_deg(runs[name]) < 1.0, name
        translation_mm = pose_error(
            relative(runs[name].results, "cam-a", "cam-b"),
            invert(POSES["cam-a"]) @ POSES["cam-b"],
        )[1]
        assert translation_mm < 200.0, name
    assert rotation_error_deg(runs["sim"]) > 3 * rotation_error_deg(runs["rgb"])
    frames = {n: r.results["cam-b"].metrics["frames_used"] for n, r in runs.items()}
    assert frames["rgb"] > 2 * frames["sim"], frames


async def test_a_kinect_pair_keeps_the_default_settings(tmp_path: Path) -> None:
    run = await skeleton_run(Rig(tmp_path))
    assert run.state == RunState.DONE, run.error
    assert settings_of(run, "cam-b") == DEPTH


async def test_a_sensor_run_against_an_rgb_sensor_uses_the_rgb_settings(tmp_path: Path) -> None:
    rig = MonoRig(tmp_path, {"cam-a": "rgb"})
    committed = {"cam-a": POSES["cam-a"], "cam-b": bumped(POSES["cam-b"], 3.0, 0.05)}
    rig.hub.use_calibration(
        rig.store.save({s: SensorCalibration(p, "points") for s, p in committed.items()})
    )
    spec = RunSpec("sensor", "cam-b", ("cam-b",), duration_s=WALK_S)
    run = await finished(rig.service().start(spec))
    assert run.state == RunState.DONE, run.error
    assert settings_of(run, "cam-b") == RGB
    rotation_deg, translation_mm = pose_error(
        run.results["cam-b"].T_world_from_sensor, POSES["cam-b"]
    )
    assert rotation_deg < 2.0 and translation_mm < 250.0, (rotation_deg, translation_mm)
