"""``skelfuse agent --pose-source ...`` (skelfuse/cli/agent_poses.py): the options' plumbing
into a moving sensor, and their usage errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.poses.posed import PosedSource
from skelfuse.agent.runner import make_hello
from skelfuse.cli import build_parser, main
from skelfuse.cli.agent import source_from_args
from skelfuse.cli.agent_poses import posed_from_args
from skelfuse.cli.values import UsageError
from skelfuse.protocol.sensor_pose import pose_matrix
from tests.fakes.openvr_api import FakeDevice, make_openvr

TRACK = "t_s,px,py,pz,qx,qy,qz,qw\n0,0,1.6,0,0,0,0,1\n0.2,0,1.6,0,0,0,0,1\n"


def posed(*options: str) -> object:
    args = build_parser().parse_args(["agent", "--id", "head-a", *options])
    return posed_from_args(args, source_from_args(args))


def pose_file(tmp_path: Path, text: str = TRACK) -> Path:
    path = tmp_path / "head.csv"
    path.write_text(text)
    return path


def test_a_pose_file_makes_the_sim_a_moving_sensor(tmp_path: Path) -> None:
    half = math.radians(20) / 2
    source = posed(
        "--pose-source",
        f"file:{pose_file(tmp_path)}",
        "--pose-space",
        "room-a",
        f"--mount=-0.1,0,0.05,{math.sin(half)},0,0,{math.cos(half)}",
        "--pose-offset-ms",
        "20",
        "--pose-loop",
    )
    assert isinstance(source, PosedSource)
    hello = make_hello("head-a", source)
    assert hello.moving and hello.pose_space == "room-a"
    capture = source.next_capture(timeout_s=1.0)
    assert capture is not None and capture.pose is not None
    # The body stands still at (0, 1.6, 0) with identity rotation: the pose is the mount's.
    transform = pose_matrix(capture.pose)
    assert transform[:3, 3] == pytest.approx([-0.1, 1.6, 0.05])
    assert transform[1, 2] == pytest.approx(-math.sin(math.radians(20)))  # looking down
    source.close()


def test_a_fixed_sensor_stays_unwrapped() -> None:
    assert not isinstance(posed(), PosedSource)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--pose-space", "room"], r"--pose-space: only for a moving sensor"),
        (["--mount", "0,0,0,0,0,0,1", "--pose-loop"], r"--mount, --pose-loop: only for"),
        (["--pose-source", "file:{file}"], r"--pose-space is required: name the tracking"),
        (["--pose-source", "vive", "--pose-space", "s"], r"vive: expected openvr or file:PATH"),
        (["--pose-source", "file:", "--pose-space", "s"], r"expected openvr or file:PATH"),
        (
            ["--pose-source", "file:{file}", "--pose-space", "s", "--mount", "1,2,3"],
            r"a mount is 7 finite numbers",
        ),
        (
            ["--pose-source", "file:{file}", "--pose-space", "s", "--mount", "a,b"],
            r"--mount 'a,b': expected X,Y,Z,QX,QY,QZ,QW",
        ),
        (
            ["--pose-source", "file:{file}", "--pose-space", "s", "--pose-device", "hmd"],
            r"--pose-device is for --pose-source openvr",
        ),
        (["--pose-source", "openvr", "--pose-space", "s", "--pose-loop"], r"--pose-loop is for"),
        (["--pose-source", "file:{missing}", "--pose-space", "s"], r"pose file .*missing.csv"),
    ],
)
def test_usage_errors(tmp_path: Path, options: list[str], message: str) -> None:
    paths = {"file": str(pose_file(tmp_path)), "missing": str(tmp_path / "missing.csv")}
    with pytest.raises(UsageError, match=message):
        posed(*(o.format(**paths) for o in options))


def test_openvr_without_a_runtime_is_a_usage_error_naming_the_cause(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # pyopenvr is in the dev extra; with or without it the agent stops with a clear message.
    code = main(["agent", "--id", "head-a", "--pose-source", "openvr", "--pose-space", "alice"])
    assert code == 2
    error = capsys.readouterr().err
    assert "--pose-source openvr: " in error
    assert "OpenVR did not start" in error or "pip install 'skelfuse[openvr]'" in error


def test_the_mutual_scenario_is_a_moving_sim_sensor() -> None:
    source = posed(
        "--source", "sim", "--scenario", "mutual", "--persons", "3", "--wearer", "2",
        "--head-axis", "pitch", "--pose-mismatch-ms", "20", "--walk-m", "0",
    )  # fmt: skip
    assert not isinstance(source, PosedSource)  # its headset attaches the poses itself
    hello = make_hello("head-2", source)
    assert hello.moving and hello.pose_space == "room"
    capture = source.next_capture(timeout_s=1.0)
    assert capture is not None and capture.pose is not None
    source.close()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--wearer", "1"], r"--wearer: only with --source sim --scenario mutual"),
        (["--head-axis", "roll", "--walk-m", "0"], r"--head-axis, --walk-m: only with"),
        (["--source", "ntu", "--scenario", "mutual"], r"a scenario of --source sim"),
        (
            ["--scenario", "mutual", "--pose-source", "openvr", "--pose-space", "s"],
            r"attach their own poses",
        ),
        (["--scenario", "mutual", "--persons", "3", "--wearer", "3"], r"wearer"),
    ],
)
def test_mutual_usage_errors(options: list[str], message: str) -> None:
    with pytest.raises(UsageError, match=message):
        posed(*options)


def test_openvr_options_reach_the_pose_source(monkeypatch: pytest.MonkeyPatch) -> None:
    # The fake pyopenvr (tests/fakes/openvr_api.py) in place of the wheel: a headset and a
    # tracker 2 m up, chosen by serial.
    up = np.hstack([np.eye(3), [[0.0], [2.0], [0.0]]])
    vr = make_openvr([FakeDevice(1, "HMD-1"), FakeDevice(3, "LHR-1A2B", lambda dt: up)])
    monkeypatch.setattr("skelfuse.agent.poses.openvr_source.import_openvr", lambda: vr)
    source = posed(
        "--pose-source", "openvr", "--pose-space", "alice", "--pose-device", "LHR-1A2B",
        "--mount", "0,0,0.1,0,0,0,1", "--pose-offset-ms", "-15",
    )  # fmt: skip
    assert isinstance(source, PosedSource)
    capture = source.next_capture(timeout_s=1.0)
    assert capture is not None and capture.pose is not None
    # OpenVR's device looks along −Z: the camera 10 cm "forward" is at z = −0.1.
    assert capture.pose.position_m == pytest.approx((0.0, 2.0, -0.1))
    (origin, seconds), *_ = vr.system.calls
    assert origin == vr.TrackingUniverseStanding and -0.2 < seconds <= -0.015
    source.close()
    assert vr.shutdowns == 1
