"""``skelfuse calibration space`` through the skelfuse command line: a tracking space's pose set by
hand is saved as a new version with the sensors kept, and a hub poses the space's moving sensors
with it; cleared again; bad input is a usage error (exit 2)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.store import CalibrationStore, SensorCalibration
from skelfuse.cli import main
from skelfuse.protocol.transform import pose_from_position_yaw_pitch
from skelfuse.protocol.wire import Hello, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings


def test_a_space_set_by_hand_poses_its_moving_sensors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = CalibrationStore(tmp_path)
    store.save({"cam": SensorCalibration(np.eye(4), "points")})
    args = ["calibration", "space", "room", "--position", "1", "0", "-2", "--yaw", "30"]
    assert main([*args, "--data", str(tmp_path)]) == 0
    assert "saved calibration version 2" in capsys.readouterr().out
    saved = store.load()
    assert saved is not None and set(saved.sensors) == {"cam"}
    expected = pose_from_position_yaw_pitch((1.0, 0.0, -2.0), 30.0)
    hub = FusionHub(Settings(), saved)
    hello = Hello("head", "sim", "t", 30.0, 0, moving=True, pose_space="room")
    hub.handle_message(b"h", [encode(hello)], 1e9, 0.0)
    pose, source = hub.pose_of("head")
    assert source == "stored" and pose is not None
    np.testing.assert_allclose(pose, expected, atol=1e-12)
    matrix = [str(v) for v in np.eye(4).reshape(16)]
    assert main(["calibration", "space", "hall", "--matrix", *matrix, "--data", str(tmp_path)]) == 0
    assert set(store.load().spaces) == {"room", "hall"}  # type: ignore[union-attr]
    assert main(["calibration", "space", "room", "--clear", "--data", str(tmp_path)]) == 0
    assert set(store.load().spaces) == {"hall"}  # type: ignore[union-attr]


@pytest.mark.parametrize(
    "args",
    [
        ["bad id", "--position", "0", "0", "0"],
        ["room", "--matrix", *["2"] * 16],
        ["nowhere", "--clear"],
    ],
)
def test_bad_input_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str]
) -> None:
    assert main(["calibration", "space", *args, "--data", str(tmp_path)]) == 2
    assert capsys.readouterr().err
