"""``skelfuse calibration lag SENSOR=SECONDS...`` through the skelfuse command line: the lag saved
as a new version with the poses and intrinsics kept, read back by a hub as the sensor's lag;
0 clears it; malformed items and sensors without a calibration are usage errors (exit 2)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from skelfuse.calibration.camera import CameraIntrinsics
from skelfuse.calibration.store import CalibrationStore, SensorCalibration
from skelfuse.cli import main
from skelfuse.protocol.transform import look_at_pose
from skelfuse.protocol.wire import Hello, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings

POSE = look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0))
INTRINSICS = CameraIntrinsics(1088, 1920, 1400.0, 1400.0, 544.0, 960.0)


def stored(tmp_path: Path) -> CalibrationStore:
    store = CalibrationStore(tmp_path)
    store.save(
        {
            "cam01": SensorCalibration(POSE, "qualisys", intrinsics=INTRINSICS),
            "cam03": SensorCalibration(POSE, "qualisys", intrinsics=INTRINSICS),
        }
    )
    return store


def test_a_lag_is_saved_as_a_new_version_and_a_hub_applies_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = stored(tmp_path)
    assert main(["calibration", "lag", "cam03=0.039", "--data", str(tmp_path)]) == 0
    assert "cam03: lag +39.0 ms" in capsys.readouterr().out
    active = store.load()
    assert active is not None and active.version == 2
    assert active.sensors["cam03"].lag_s == 0.039 and active.sensors["cam01"].lag_s is None
    assert active.sensors["cam03"].intrinsics == INTRINSICS
    assert np.array_equal(active.sensors["cam03"].T_world_from_sensor, POSE)
    hub = FusionHub(Settings(), active)
    hub.handle_message(b"a", [encode(Hello("cam03", "rgb", "t", 60.0, 0))], 1e9, 0.0)
    assert hub.sensors["cam03"].lag_s == 0.039
    assert main(["calibration", "lag", "cam03=0", "--data", str(tmp_path)]) == 0
    cleared = store.load()
    assert cleared is not None and cleared.sensors["cam03"].lag_s is None


@pytest.mark.parametrize(
    ("items", "message"),
    [
        (["cam03"], "expected SENSOR=SECONDS"),
        (["cam03=soon"], "expected SENSOR=SECONDS"),
        (["cam03=nan"], "expected SENSOR=SECONDS"),
        (["cam03=60"], "within +-10"),
        (["=0.1"], "expected SENSOR=SECONDS"),
        (["cam03=0.1", "cam03=0.2"], "named twice"),
        (["cam09=0.1"], "no calibrated sensor 'cam09'"),
    ],
)
def test_bad_items_are_usage_errors_and_nothing_is_saved(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], items: list[str], message: str
) -> None:
    store = stored(tmp_path)
    assert main(["calibration", "lag", *items, "--data", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err
    assert store.versions() == [1]


def test_without_a_calibration_it_says_to_make_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["calibration", "lag", "cam03=0.04", "--data", str(tmp_path)]) == 2
    assert "holds: none" in capsys.readouterr().err
