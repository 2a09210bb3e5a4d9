"""NTU RGB+D .skeleton reader, the ntu source, and three cameras fused offline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.sources.base import SensorError
from skelfuse.agent.sources.ntu import NtuSource
from skelfuse.fusion.settings import BoneSettings
from skelfuse.protocol.ntu import NtuFormatError, parse_ntu_name, read_ntu_skeleton
from skelfuse.protocol.transform import apply, invert, look_at_pose
from skelfuse.protocol.wire import Frame, encode

DATA = Path(__file__).resolve().parents[1] / "data"
FIXTURE = DATA / "S001C001P001R001A001.skeleton"


def test_reads_frames_bodies_joints_and_states() -> None:
    frames = read_ntu_skeleton(FIXTURE)
    assert [len(f) for f in frames] == [1, 2, 0]
    body = frames[0][0]
    assert body.tracking_id == 72057594037931101
    assert body.joints_m.shape == (25, 3) and body.joints_m.dtype == np.float32
    assert body.states[7] == 1 and body.states[21] == 0 and body.states[0] == 2
    np.testing.assert_allclose(frames[1][0].joints_m - body.joints_m, 0.01, atol=1e-5)
    encode(Frame(1, 0, frames[1]))  # wire-valid


def test_name_gives_camera_and_performance() -> None:
    name = parse_ntu_name(FIXTURE)
    assert name is not None and name.camera == 1 and name.action == 1
    assert name.performance == "S001P001R001A001"
    assert parse_ntu_name("other.skeleton") is None


def test_truncated_file_names_the_line(tmp_path: Path) -> None:
    broken = tmp_path / "broken.skeleton"
    broken.write_text("\n".join(FIXTURE.read_text().split("\n")[:20]))
    with pytest.raises(NtuFormatError, match="ends early"):
        read_ntu_skeleton(broken)
    with pytest.raises(SensorError, match="ends early"):  # the agent reports it as a sensor error
        NtuSource(broken)


def test_source_paces_at_30_fps_from_a_shared_start() -> None:
    now = [1_000_000_000_000_000_000]
    slept: list[float] = []

    def sleep(s: float) -> None:
        slept.append(s)
        now[0] += round(s * 1e9)

    pose = look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0))
    source = NtuSource(FIXTURE, pose, start_unix_s=1_000_000_000.0, wall_clock_ns=lambda: now[0],
                       sleep=sleep)  # fmt: skip
    captures = [source.next_capture(1.0) for _ in range(3)]
    assert [c.t_capture_ns for c in captures if c] == [
        1_000_000_000_000_000_000 + i * round(1e9 / 30) for i in range(3)
    ]
    assert source.pose_hint() is not None and source.sensor_type == "kinect_v2"
    assert source.next_capture(0.01) is None  # end of file, no loop


def test_three_cameras_with_poses_fuse_into_one_person(tmp_path: Path) -> None:
    from skelfuse.protocol.recording_file import write_recording
    from skelfuse.recording.ntu_import import ntu_recording
    from skelfuse.recording.replay import replay
    from skelfuse.server.settings import FusionSettings, Settings

    # Three views of the same skeleton: write camera files whose sensor-frame joints come from
    # one world skeleton through three known poses.
    frames = read_ntu_skeleton(FIXTURE)
    world = frames[0][0].joints_m.astype(np.float64) + np.array([0.0, 1.2, -3.0])
    poses = [look_at_pose(p, (0.0, 1.0, 0.0)) for p in ((0, 1, 3), (2.6, 1, -1.5), (-2.6, 1, -1.5))]
    paths = []
    for k, pose in enumerate(poses):
        sensor = apply(invert(pose), world)
        text = [str(60)]
        for _ in range(60):
            text += ["1", "42 0 1 2 1 3 0 0 0 2", "25"]
            text += [f"{x:.6f} {y:.6f} {z:.6f} 0 0 0 0 1 0 0 0 2" for x, y, z in sensor]
        path = tmp_path / f"S001C00{k + 1}P001R001A001.skeleton"
        path.write_text("\n".join(text) + "\n")
        paths.append(path)
    header, records = ntu_recording(paths, poses)
    recording = tmp_path / "ntu.sfrec"
    write_recording(recording, header, records)
    # The fixture is one real Kinect v2 frame whose left and right bones differ by up to 25 cm;
    # the default online bone estimate pools left and right and would (rightly) even them out.
    # This test is about the import and the poses: every view agrees, so fusion must give back
    # exactly the world skeleton.
    settings = Settings(fusion=FusionSettings(bones=BoneSettings(symmetric=False)))
    fused = list(replay(recording, settings))
    last = fused[-1]
    assert len(last.persons) == 1
    assert set(last.persons[0].sources) == {"ntu-C001", "ntu-C002", "ntu-C003"}
    np.testing.assert_allclose(last.persons[0].joints, world, atol=1e-3)


def test_replay_of_a_broken_ntu_file_is_a_usage_error_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from skelfuse.cli import main

    broken = tmp_path / "S001C001P001R001A001.skeleton"
    broken.write_text("garbage\n")
    assert main(["replay", str(broken)]) == 2
    assert "expected the frame count" in capsys.readouterr().err
