"""PosedSource (agent/poses/posed.py): the simulator's captures with a pose file's or a fake
OpenVR headset's poses at their capture instants, the mount, and what happens without a pose."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.poses.base import compose, mount_matrix
from skelfuse.agent.poses.openvr_source import OpenVRPoseSource
from skelfuse.agent.poses.pose_file import FilePoseSource, read_pose_file
from skelfuse.agent.poses.posed import PosedSource
from skelfuse.agent.runner import make_hello
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sources.base import SensorError
from skelfuse.agent.sources.sim import SimSource
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import pose_from_matrix, pose_matrix
from skelfuse.protocol.transform import look_at_pose
from tests.fakes.openvr_api import FakeDevice, make_openvr

START_NS = 1_700_000_000_000_000_000


class FakeClock:
    """Wall clock (ns) that ``sleep`` advances."""

    def __init__(self) -> None:
        self.now_ns = START_NS

    def __call__(self) -> int:
        return self.now_ns

    def sleep(self, seconds: float) -> None:
        self.now_ns += round(seconds * 1e9)


def sim(clock: FakeClock) -> SimSource:
    return SimSource(
        ProceduralPerformer(1),
        look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0)),
        wall_clock_ns=clock,
        sleep=clock.sleep,
    )


def walking_file(tmp_path: Path, seconds: float = 1.0) -> Path:
    """A head walking along +X at 1 m/s, 100 Hz, relative times."""
    rows = [f"{t / 100:.2f},{t / 100:.2f},1.6,0,0,0,0,1" for t in range(round(seconds * 100) + 1)]
    path = tmp_path / "walk.csv"
    path.write_text("t_s,px,py,pz,qx,qy,qz,qw\n" + "\n".join(rows) + "\n")
    return path


def test_each_capture_carries_the_pose_at_its_stamp(tmp_path: Path) -> None:
    clock = FakeClock()
    inner = sim(clock)
    poses = FilePoseSource(read_pose_file(walking_file(tmp_path)), clock_ns=clock)
    source = PosedSource(inner, poses, "room-a", offset_ns=20_000_000)
    for _ in range(10):
        capture = source.next_capture(timeout_s=1.0)
        assert capture is not None and capture.pose is not None
        expected_x = (capture.t_capture_ns + 20_000_000 - START_NS) / 1e9
        assert capture.pose.position_m == pytest.approx((expected_x, 1.6, 0.0))
        assert capture.bodies  # the inner capture, untouched otherwise
    assert source.posed == 10 and not source.unposed
    hello = make_hello("head-a", source)
    assert hello.moving and hello.pose_space == "room-a" and hello.pose_hint is None
    assert hello.sensor_type == "sim" and hello.fps == inner.fps
    # The runner's optional hooks are the inner source's.
    assert source.wall_clock_ns() == clock.now_ns
    assert "depth_cloud" in source.request_handlers()
    assert getattr(source, "waits_for_server", False) is False
    with pytest.raises(AttributeError):
        _ = source.anything_else  # type: ignore[attr-defined]


def test_captures_without_a_pose_are_counted_and_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    clock = FakeClock()
    seconds = [0.0]
    poses = FilePoseSource(read_pose_file(walking_file(tmp_path, 0.2)), clock_ns=clock)
    source = PosedSource(sim(clock), poses, "room-a", report_s=0.6, monotonic=lambda: seconds[0])
    with caplog.at_level(logging.WARNING, logger="skelfuse.agent.poses.posed"):
        captures = []
        for _ in range(15):  # 0.5 s at 30 fps: the track ends (+50 ms held) at 0.25 s
            capture = source.next_capture(timeout_s=1.0)
            assert capture is not None
            captures.append(capture)
            seconds[0] += 0.0625  # monotonic seconds between reads
    posed = [c for c in captures if c.pose is not None]
    assert len(posed) == 8 and all(c.pose is None for c in captures[8:])
    assert source.unposed == {"after the pose file's last sample": 7}
    messages = [r.getMessage() for r in caplog.records]
    assert messages[0] == "captures without a pose are not sent: after the pose file's last sample"
    # A summary once report_s had passed (capture 10, at 0.625 s), and no more within 0.6 s.
    assert messages[1:] == ["8 captures posed, unposed: 3 after the pose file's last sample"]


def test_a_headset_mounted_camera_through_fake_openvr() -> None:
    clock = FakeClock()
    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    turned_left = np.array([[c, 0, s, 1.0], [0, 1, 0, 1.7], [-s, 0, c, -2.0]])
    vr = make_openvr([FakeDevice(1, "HMD-1", lambda dt: turned_left)])
    # The depth camera 10 cm in front of the headset, pitched 20° down (about its +X, left).
    half = math.radians(20) / 2
    mount = mount_matrix((0.0, 0.0, 0.1, math.sin(half), 0.0, 0.0, math.cos(half)))
    headset = OpenVRPoseSource(vr=vr, clock_ns=clock)
    source = PosedSource(sim(clock), headset, "openvr", mount=mount)
    capture = source.next_capture(timeout_s=1.0)
    assert capture is not None and capture.pose is not None
    transform = pose_matrix(capture.pose)
    # The headset looks along the space's −X: the camera sits 10 cm further −X and looks
    # along −X, 20° down.
    assert transform[:3, 3] == pytest.approx([0.9, 1.7, -2.0])
    down = math.radians(20)
    assert transform[:3, 2] == pytest.approx([-math.cos(down), -math.sin(down), 0.0], abs=1e-6)
    assert transform[:3, 0] == pytest.approx([0.0, 0.0, 1.0], abs=1e-6)  # its left: +Z
    source.close()
    assert vr.shutdowns == 1


@pytest.mark.parametrize(
    ("values", "message"),
    [((0, 0, 0, 0, 0, 0), "7 finite numbers"), ((0, 0, 0, 0, 0, 0, 2), "norm 2.000")],
)
def test_bad_mounts(values: tuple[float, ...], message: str) -> None:
    with pytest.raises(SensorError, match=message):
        mount_matrix(values)


def test_compose_is_the_matrix_product() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        a, b = (
            SensorPose(
                tuple(rng.normal(size=3)),  # type: ignore[arg-type]
                tuple(q / np.linalg.norm(q)),  # type: ignore[arg-type]
            )
            for q in rng.normal(size=(2, 4))
        )
        expected = pose_from_matrix(pose_matrix(a) @ pose_matrix(b))
        got = compose(a, b)
        assert got.position_m == pytest.approx(expected.position_m, abs=1e-12)
        assert got.rotation_xyzw == pytest.approx(expected.rotation_xyzw, abs=1e-12)
        assert got.rotation_xyzw[3] >= 0
