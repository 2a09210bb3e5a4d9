"""A sensor's calibrated clock lag travels with a recording: the server writes it into the
header's calibration (only when set: files without lags keep their bytes), and the offline
replay fuses with it, as the live server did."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import msgpack
import numpy as np
import pytest

from bench.recording.replay import generate_recording
from skelfuse.calibration.store import Calibration, SensorCalibration
from skelfuse.protocol.feed import frame_json
from skelfuse.protocol.recording_file import (
    Header,
    RecordingError,
    SensorPose,
    read_recording,
    write_recording,
)
from skelfuse.protocol.wire import Hello, decode, encode
from skelfuse.recording.replay import calibration_of, replay
from skelfuse.server.hub import FusionHub
from skelfuse.server.routes_recordings import _header_from_hub
from skelfuse.server.settings import Settings


def digest(path: Path) -> list[str]:
    return [
        json.dumps(frame_json(f, include_raw=True), separators=(",", ":")) for f in replay(path)
    ]


def with_lags(source: Path, target: Path, lags: dict[str, float | None]) -> Path:
    """``source`` with each sensor's pose hint stored as its calibration, with ``lags``."""
    header, records = read_recording(source)
    calibration = {}
    for record in records:
        hello = decode(record.payload) if record.kind == "hello" else None
        if isinstance(hello, Hello) and hello.pose_hint is not None:
            lag = lags.get(record.sensor_id)
            calibration[record.sensor_id] = SensorPose(hello.pose_hint, "sim", "stored", lag)
    write_recording(target, dataclasses.replace(header, calibration=calibration), records)
    return target


def test_the_header_keeps_a_lag_and_only_writes_it_when_set() -> None:
    pose = np.eye(4)
    plain = Header(1.5, "0.1.0", "t", {"k1": SensorPose(pose, "manual", "stored")})
    lagged = Header(1.5, "0.1.0", "t", {"k1": SensorPose(pose, "manual", "stored", 0.039)})
    assert "lag_s" not in msgpack.unpackb(plain.to_msgpack())["calibration"]["k1"]
    back = Header.from_object(msgpack.unpackb(lagged.to_msgpack()), "test")
    assert back.calibration["k1"].lag_s == 0.039
    restored = calibration_of(back)
    assert restored is not None and restored.sensors["k1"].lag_s == 0.039
    broken = msgpack.unpackb(lagged.to_msgpack())
    broken["calibration"]["k1"]["lag_s"] = "late"
    with pytest.raises(RecordingError, match="bad lag_s"):
        Header.from_object(broken, "test")


def test_the_server_records_the_lag_of_its_calibration() -> None:
    lags: dict[str, float | None] = {"cam-a": 0.04, "cam-b": None}
    sensors = {s: SensorCalibration(np.eye(4), "points", lag_s=lag) for s, lag in lags.items()}
    hub = FusionHub(Settings(), Calibration(3, 0.0, sensors))
    for i, sensor_id in enumerate(lags):
        hub.handle_message(bytes([i]), [encode(Hello(sensor_id, "rgb", "t", 30.0, 0))], 1e9, 0.0)
    header = _header_from_hub(hub, "take")
    assert {s: p.lag_s for s, p in header.calibration.items()} == lags


def test_the_replay_fuses_with_the_recorded_lag(tmp_path: Path) -> None:
    source = tmp_path / "sim.sfrec"
    generate_recording(source, sensors=2, persons=1, duration_s=2.0, seed=3)
    original = digest(with_lags(source, tmp_path / "none.sfrec", {}))
    assert len(original) > 30
    first = sorted(read_recording(tmp_path / "none.sfrec")[0].calibration)[0]
    assert digest(with_lags(source, tmp_path / "zero.sfrec", {first: 0.0})) == original
    assert digest(with_lags(source, tmp_path / "lag.sfrec", {first: 0.04})) != original
