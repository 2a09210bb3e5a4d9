"""``skelfuse agent --source mono --calibration FILE`` (skelfuse/cli/agent_lens.py): a calibration
file's camera as the mono source's lens and pose, checked on the real clip's four cameras
(tests/data/pose2sim_single_calib.qca.txt with tests/data/mono_landmarks.npz)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.sources.base import SensorError
from skelfuse.agent.sources.mono import MonoSource
from skelfuse.cli import agent as agent_cli
from skelfuse.cli.agent_lens import calibrated_lens
from skelfuse.cli.values import UsageError
from skelfuse.protocol.mediapipe_pose import body_from_landmarks
from skelfuse.protocol.skeleton import JointId
from skelfuse.protocol.transform import apply
from tests.unit.test_mono_source import BlankFrames, Clock, StoredLandmarks

DATA = Path(__file__).resolve().parents[1] / "data"
CALIBRATION = DATA / "pose2sim_single_calib.qca.txt"
CAMERAS = ("cam01", "cam02", "cam03", "cam04")


def test_four_calibrated_cameras_put_the_person_in_one_place_standing_on_the_floor() -> None:
    with np.load(DATA / "mono_landmarks.npz") as data:
        clip = {key: data[key] for key in data.files}
    placed = {}
    for cam in CAMERAS:
        lens, pose = calibrated_lens(CALIBRATION, None, cam)
        width, height = (int(v) for v in clip[f"{cam}_size_wh"])
        k, undistort = lens(width, height)
        assert undistort is not None  # Qualisys gives k1, k2, p1, p2
        pixels = clip[f"{cam}_image_px"][0].astype(np.float64)
        pixels[:, :2] = undistort(pixels[:, :2])
        body = body_from_landmarks(
            pixels, clip[f"{cam}_world_m"][0], clip[f"{cam}_visibility"][0], (width, height), k
        )
        placed[cam] = apply(pose, body.joints_m.astype(np.float64))  # world: +Y up, floor y = 0
    middle = np.median([p[JointId.SPINE_BASE] for p in placed.values()], axis=0)
    for cam, joints in placed.items():
        assert np.linalg.norm(joints[JointId.SPINE_BASE] - middle) < 0.35, cam
        assert 0.7 < joints[JointId.SPINE_BASE, 1] < 1.1, cam
        assert 1.4 < joints[JointId.HEAD, 1] < 1.8, cam
        assert min(joints[JointId.FOOT_LEFT, 1], joints[JointId.FOOT_RIGHT, 1]) < 0.3, cam


def test_undistortion_inverts_the_lens_and_the_frames_must_fit() -> None:
    lens, _ = calibrated_lens(CALIBRATION, "qualisys", "cam02")
    k, undistort = lens(1088, 1920)
    assert undistort is not None
    corner = np.array([[50.0, 60.0], [1000.0, 1850.0], [k.cx, k.cy]])
    ideal = undistort(corner)
    assert np.abs(ideal[:2] - corner[:2]).max() > 1.0  # the lens bends the corners
    np.testing.assert_allclose(ideal[2], corner[2], atol=1e-9)  # not the centre
    with pytest.raises(SensorError, match="portrait"):
        lens(1920, 1080)


def test_a_source_with_a_calibrated_lens_places_bodies() -> None:
    lens, pose = calibrated_lens(CALIBRATION, None, "cam02")
    clock = Clock()
    source = MonoSource(
        video="clip.mp4", lens=lens, pose=pose, frames=BlankFrames(3),
        detector=StoredLandmarks(), wall_clock_ns=clock, sleep=clock.sleep,
    )  # fmt: skip
    capture = source.next_capture(0.1)
    assert capture is not None and len(capture.bodies) == 1
    hint = source.pose_hint()
    assert hint is not None and np.array_equal(hint[0], pose) and hint[1] == "manual"
    assert 2.0 < float(capture.bodies[0].joints_m[JointId.SPINE_BASE, 2]) < 4.0


def test_command_line_errors_say_what_to_do(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="calibration-camera"):
        calibrated_lens(CALIBRATION, None, None)  # four cameras, none named
    with pytest.raises(UsageError, match="no camera 'cam09'"):
        calibrated_lens(CALIBRATION, None, "cam09")
    odd = tmp_path / "calib.dat"
    odd.write_text("x")
    with pytest.raises(UsageError, match="calibration-format"):
        calibrated_lens(odd, None, None)
    parser = argparse.ArgumentParser()
    agent_cli.add_parser(parser.add_subparsers())
    args = parser.parse_args(
        ["agent", "--id", "c", "--source", "mono", "--video", "v.mp4", "--intrinsics",
         "1,1,1,1", "--calibration", str(CALIBRATION)]
    )  # fmt: skip
    with pytest.raises(UsageError, match="not both"):
        agent_cli.source_from_args(args)
