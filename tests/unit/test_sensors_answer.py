"""Each sensor's learned error as apps see it: ``/api/sensors``'s ``learned_error`` (null for a
sensor fusion has not seen a person through), the ``/metrics`` gauges, and a recalibrated
sensor re-learned from its prior while the others keep what they learned."""

from __future__ import annotations

import numpy as np
import pytest

from skelfuse.calibration.store import Calibration, SensorCalibration
from skelfuse.fusion.priors import KINECT_V2
from skelfuse.fusion.rig_errors import SensorErrors
from skelfuse.protocol.transform import look_at_pose
from skelfuse.server.hub import FusionHub
from skelfuse.server.metrics import learned_error_metrics
from skelfuse.server.sensors_answer import sensors_answer
from skelfuse.server.settings import Settings

ROWS: list[dict[str, object]] = [
    {"id": "cam-a", "connected": True, "fps": 30.0},
    {"id": "cam-b", "connected": True, "fps": 29.5},
]
LEARNED = {
    "cam-a": SensorErrors({"trunk": 12.345, "arms": 20.04, "legs": 45.06}, 321.46, True),
}


def test_learned_error_per_sensor_rounded_and_null_for_an_unseen_sensor() -> None:
    answer = sensors_answer(ROWS, LEARNED, {"not_registered": 2}).model_dump()
    a, b = answer["sensors"]
    assert a["learned_error"] == {
        "trunk_mm": 12.3, "arms_mm": 20.0, "legs_mm": 45.1, "samples": 321.5, "learned": True,
    }  # fmt: skip
    assert b["learned_error"] is None
    # The engine's own fields pass through unchanged, in its order.
    assert [a["id"], a["connected"], a["fps"]] == ["cam-a", True, 30.0]
    assert b["fps"] == 29.5
    assert answer["rejected_unregistered"] == {"not_registered": 2}


def test_metrics_gauge_every_group_of_every_seen_sensor() -> None:
    errors = {
        **LEARNED,
        "cam-0": SensorErrors({"trunk": 9.0, "arms": 14.0, "legs": 18.0}, 7.0, False),
    }
    error, samples = learned_error_metrics(errors)
    values = {(s.labels["sensor"], s.labels["group"]): s.value for s in error.samples}
    assert values == {
        ("cam-0", "trunk"): 9.0, ("cam-0", "arms"): 14.0, ("cam-0", "legs"): 18.0,
        ("cam-a", "trunk"): 12.345, ("cam-a", "arms"): 20.04, ("cam-a", "legs"): 45.06,
    }  # fmt: skip
    assert {s.labels["sensor"]: s.value for s in samples.samples} == {"cam-0": 7.0, "cam-a": 321.46}
    assert error.name == "skelfuse_sensor_learned_error_mm"
    assert samples.name == "skelfuse_sensor_learned_error_samples"


def calibration(version: int, poses: dict[str, np.ndarray]) -> Calibration:
    sensors = {s: SensorCalibration(pose, "test") for s, pose in poses.items()}
    return Calibration(version, 0.0, sensors)


def test_a_calibration_that_moves_a_sensor_restarts_its_learned_error_only(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    hub = FusionHub(Settings())
    errors = hub.pipeline.errors
    errors.rows_of(["a", "b", "c"], [KINECT_V2] * 3)  # fusion has seen all three
    forgotten: list[str] = []
    forget = errors.forget
    monkeypatch.setattr(errors, "forget", lambda s, p=None: (forgotten.append(s), forget(s, p)))
    pose_a = look_at_pose((0.0, 1.0, 3.0), (0.0, 1.0, 0.0))
    pose_b = look_at_pose((2.6, 1.4, -1.5), (0.0, 1.0, 0.0))

    hub.use_calibration(calibration(1, {"a": pose_a, "b": pose_b}))  # c stays uncalibrated
    assert sorted(forgotten) == ["a", "b"]
    forgotten.clear()
    hub.use_calibration(calibration(2, {"a": pose_a.copy(), "b": pose_b.copy()}))  # the same
    assert forgotten == []
    moved = pose_b.copy()
    moved[0, 3] += 0.01  # 1 cm
    hub.use_calibration(calibration(3, {"a": pose_a, "b": moved}))
    assert forgotten == ["b"]
    forgotten.clear()
    hub.use_calibration(calibration(4, {"b": moved}))  # a falls back to uncalibrated
    assert forgotten == ["a"]
