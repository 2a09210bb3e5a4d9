"""OpenVR poses (agent/poses/openvr_source.py) against a fake of pyopenvr (tests/fakes/
openvr_api.py), and the real ``openvr`` wheel's start without a runtime (no headset here)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from skelfuse.agent.poses.openvr_source import OpenVRPoseSource, check_openvr
from skelfuse.agent.sources.base import SensorError
from skelfuse.protocol.sensor_pose import pose_matrix
from tests.fakes.openvr_api import FakeDevice, make_openvr
from tests.support import unavailable

NOW_NS = 1_700_000_000_000_000_000
HMD, CONTROLLER, TRACKER = 1, 2, 3


def yawed_headset(dt: float) -> np.ndarray:
    """OpenVR device → standing space: the headset at (1, 1.7, −2) + dt·(1 m/s along X),
    turned 90° left (looking along OpenVR's −X instead of −Z)."""
    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    return np.array([[c, 0, s, 1.0 + dt], [0, 1, 0, 1.7], [-s, 0, c, -2.0]])


def source_for(devices: list[FakeDevice], device: str = "hmd", **kw: float) -> OpenVRPoseSource:
    vr = make_openvr(devices)
    return OpenVRPoseSource(device, vr=vr, clock_ns=lambda: NOW_NS, **kw)  # type: ignore[arg-type]


def test_a_headset_pose_in_sensor_axes_asked_for_the_capture_instant() -> None:
    vr = make_openvr([FakeDevice(HMD, "HMD-1", yawed_headset)])
    source = OpenVRPoseSource("hmd", vr=vr, clock_ns=lambda: NOW_NS)
    assert vr.app_types == [vr.VRApplication_Background]
    pose = source.pose_at(NOW_NS - 30_000_000)  # a capture 30 ms old
    assert vr.system.calls == [(vr.TrackingUniverseStanding, pytest.approx(-0.03))]
    assert pose is not None
    transform = pose_matrix(pose)
    # Sensor axes: +Z forward, +X left. Looking along −X (space), 2 m ahead is 2 m further −X;
    # its left is +Z of the space. The position is the one 30 ms back (x = 1 − 0.03).
    ahead = transform @ [0.0, 0.0, 2.0, 1.0]
    left = transform @ [1.0, 0.0, 0.0, 1.0]
    assert ahead[:3] == pytest.approx([0.97 - 2.0, 1.7, -2.0], abs=1e-6)
    assert left[:3] == pytest.approx([0.97, 1.7, -1.0], abs=1e-6)


def test_no_pose_too_far_back_or_ahead_or_when_tracking_is_lost() -> None:
    lost = FakeDevice(HMD, "HMD-1", lambda dt: None)
    source = source_for([lost])
    assert source.pose_at(NOW_NS) is None and "not valid" in source.last_miss
    source = source_for([FakeDevice(HMD, "HMD-1", connected=False)])
    assert source.pose_at(NOW_NS) is None and "not connected" in source.last_miss
    source = source_for([FakeDevice(HMD, "HMD-1")], max_lookback_s=0.1)
    assert source.pose_at(NOW_NS - 100_000_000) is not None
    assert source.pose_at(NOW_NS - 101_000_000) is None
    assert source.last_miss == "capture older than 100 ms (OpenVR)"
    assert source.pose_at(NOW_NS + 60_000_000) is None and "ahead" in source.last_miss
    with pytest.raises(SensorError, match=r"0\.\.0\.2 s"):
        source_for([FakeDevice(HMD, "HMD-1")], max_lookback_s=0.3)


def test_a_device_chosen_by_serial() -> None:
    devices = [
        FakeDevice(HMD, "HMD-1"),
        FakeDevice(CONTROLLER, "CTRL-1"),
        FakeDevice(0, ""),
        FakeDevice(TRACKER, "LHR-1A2B", lambda dt: np.hstack([np.eye(3), [[5.0], [0], [0]]])),
    ]
    source = source_for(devices, "LHR-1A2B")
    assert source.index == 3
    pose = source.pose_at(NOW_NS)
    assert pose is not None and pose.position_m == (5.0, 0.0, 0.0)
    # OpenVR's identity (looking along −Z) is a half turn about Y in sensor axes.
    assert pose.rotation_xyzw == pytest.approx((0.0, 1.0, 0.0, 0.0))
    vr = make_openvr(devices)
    with pytest.raises(SensorError, match=r"serial 'LHR-9' \(serials: HMD-1, CTRL-1, LHR-1A2B\)"):
        OpenVRPoseSource("LHR-9", vr=vr)
    assert vr.shutdowns == 1


def test_no_headset_is_an_error() -> None:
    with pytest.raises(SensorError, match="no headset"):
        source_for([FakeDevice(TRACKER, "LHR-1")])


@pytest.mark.parametrize(
    ("error", "hint"),
    [
        ("InitError_Init_PathRegistryNotFound", "no OpenVR runtime is installed"),
        ("InitError_Init_NoServerForBackgroundApp", "SteamVR is not running"),
        ("InitError_Init_HmdNotFound", "finds no headset"),
        ("InitError_Unknown", "SteamVR's own logs"),
    ],
)
def test_a_runtime_that_does_not_start_says_why(error: str, hint: str) -> None:
    with pytest.raises(SensorError, match=rf"OpenVR did not start \({error}\): .*{hint}"):
        OpenVRPoseSource(vr=make_openvr(init_error=error))


def test_close_shuts_openvr_down_once() -> None:
    vr = make_openvr()
    source = OpenVRPoseSource(vr=vr)
    source.close()
    source.close()
    assert vr.shutdowns == 1


def test_the_real_wheel_without_a_runtime_gives_the_clear_error() -> None:
    if importlib.util.find_spec("openvr") is None:
        unavailable("pyopenvr not installed", "the dev extra installs openvr (pyproject.toml)")
    # This machine has no SteamVR: libopenvr_api finds no path registry and init fails.
    with pytest.raises(SensorError, match=r"OpenVR did not start \(InitError_Init_\w+\)"):
        OpenVRPoseSource()


def test_doctor_finds_the_runtime_by_its_path_registry(tmp_path: Path) -> None:
    if importlib.util.find_spec("openvr") is None:
        unavailable("pyopenvr not installed", "the dev extra installs openvr (pyproject.toml)")
    env = {"XDG_CONFIG_HOME": str(tmp_path / "config"), "LOCALAPPDATA": str(tmp_path / "local")}
    available, reason = check_openvr(tmp_path, env)
    assert not available and "install SteamVR and run it once" in reason
    folder = {"win32": tmp_path / "local" / "openvr", "darwin": tmp_path / "Library" /
              "Application Support" / "OpenVR" / ".openvr"}.get(sys.platform,
              tmp_path / "config" / "openvr")  # fmt: skip
    folder.mkdir(parents=True)
    (folder / "openvrpaths.vrpath").write_text("{}")
    available, reason = check_openvr(tmp_path, env)
    assert available and "SteamVR must be running" in reason
