"""Recordings of moving sensors: the server's header keeps their tracking space's transform and
the rebuilt hello says they move; ``skelfuse replay`` fuses them as the live hub did."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from skelfuse.agent.sources.replay import ReplaySource
from skelfuse.calibration.store import Calibration, SpaceCalibration
from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.settings import HubSettings
from skelfuse.protocol.recording_file import Header, Record, write_recording
from skelfuse.protocol.wire import Frame, encode
from skelfuse.recording.replay import calibration_of, replay
from skelfuse.server.hub import FusionHub
from skelfuse.server.routes_recordings import _header_from_hub
from tests.unit.test_moving_sensors import (
    FPS,
    T0,
    WORLD_FROM_SPACE,
    body,
    head_sensor,
    moving_hello,
    seen,
    space_pose,
    wearer_truth,
)


def mutual_records(seconds: float) -> list[Record]:
    """Two head-mounted sensors capturing each other's wearer (tests/unit/test_moving_sensors),
    as the server records them: hellos, then frames with their poses, at arrival times."""
    records = [
        Record(round(T0 * 1e9), f"head-{k}", "hello", moving_hello(f"head-{k}")) for k in (0, 1)
    ]
    for i in range(round(seconds * FPS)):
        t = i / FPS
        for k in (0, 1):
            pose = head_sensor(k, t)
            frame = Frame(
                i + 1, round((T0 + t) * 1e9), (body(100 + k, seen(pose, wearer_truth(1 - k, t))),),
                None, space_pose(pose),
            )  # fmt: skip
            records.append(
                Record(round((T0 + t + 0.004) * 1e9), f"head-{k}", "frame", encode(frame))
            )
    return records


def test_the_header_keeps_the_space_and_the_replay_restores_it() -> None:
    calibration = Calibration(
        4, 0.0, {}, spaces={"room": SpaceCalibration(WORLD_FROM_SPACE, "icp")}
    )
    hub = FusionHub(HubSettings(), calibration)
    for k in (0, 1):
        hub.handle_message(bytes([k]), [moving_hello(f"head-{k}")], T0, 0.0)
    header = _header_from_hub(hub, "take")
    assert list(header.calibration) == ["space:room"]
    assert header.calibration["space:room"].method == "icp"
    assert header.sensors["head-0"] == {"type": "sim", "pose_state": "stored", "pose_space": "room"}
    restored = calibration_of(header)
    assert restored is not None and restored.sensors == {}
    np.testing.assert_array_equal(restored.spaces["room"].T_world_from_space, WORLD_FROM_SPACE)


def test_the_replay_fuses_moving_sensors_as_the_live_hub_does(tmp_path: Path) -> None:
    records = mutual_records(2.0)
    settings = HubSettings()
    settings = dataclasses.replace(
        settings,
        fusion=dataclasses.replace(
            settings.fusion,
            alignment=dataclasses.replace(settings.fusion.alignment, policy="aligned"),
        ),
    )
    calibration = Calibration(1, 0.0, {}, spaces={"room": SpaceCalibration(WORLD_FROM_SPACE, "m")})
    live = FusionHub(settings, calibration)
    path = tmp_path / "mutual.sfrec"
    write_recording(path, recorded_header(calibration), records)
    expected: list[FusedFrame] = []
    for record in records:
        now = record.t_server_ns / 1e9
        live.handle_message(record.sensor_id.encode(), [record.payload], now, now - T0)
        if record.kind == "frame" and (fused := live.fuse_step(now)) is not None:
            expected.append(fused)
    got = list(replay(path))
    assert len(got) == len(expected) > 40
    for a, b in zip(got, expected, strict=True):
        assert a.t_s == b.t_s and len(a.persons) == len(b.persons)
        for p, q in zip(a.persons, b.persons, strict=True):
            assert p.joints.tobytes() == q.joints.tobytes()
    # ... and where the truth is.
    last = got[-1]
    assert len(last.persons) == 2
    for person in last.persons:
        wearer = 1 - int(person.views[0].sensor_id[-1])
        error = np.linalg.norm(person.joints - wearer_truth(wearer, last.t_s - T0), axis=1)
        assert np.nanmedian(error) < 0.02


def recorded_header(calibration: Calibration) -> Header:
    """The header a server with ``calibration`` writes with the two head sensors online."""
    hub = FusionHub(HubSettings(), calibration)
    for k in (0, 1):
        hub.handle_message(bytes([k]), [moving_hello(f"head-{k}")], T0, 0.0)
    return _header_from_hub(hub, "take")


def test_a_recorded_moving_sensor_plays_back_live_as_one(tmp_path: Path) -> None:
    path = tmp_path / "mutual.sfrec"
    space = SpaceCalibration(WORLD_FROM_SPACE, "m")
    write_recording(path, recorded_header(Calibration(1, 0.0, {}, spaces={"room": space})),
                    mutual_records(0.5))  # fmt: skip
    clock = [10**18]
    source = ReplaySource(path, "head-1", wall_clock_ns=lambda: clock[0], sleep=lambda _: None)
    assert source.pose_space == "room"
    hint = source.pose_hint()
    assert hint is not None
    np.testing.assert_array_equal(hint[0], WORLD_FROM_SPACE)
    capture = source.next_capture(1.0)
    assert capture is not None and capture.pose == space_pose(head_sensor(1, 0.0))
    fixed = tmp_path / "fixed.sfrec"
    frame = Frame(1, 5, ())
    write_recording(fixed, Header(0.0, "t"), [Record(5, "cam", "frame", encode(frame))])
    assert ReplaySource(fixed, "cam").pose_space is None
