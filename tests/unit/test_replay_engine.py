"""Offline replay feeds decoded records to the fusion engine (recording/replay.py) and fuses what
the server's hub (server/hub.py) fuses from the same wire bytes, sessions included: a sensor that
falls silent is marked offline, its frames refused until it says hello again. Recorded time only."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from bench.recording.replay import generate_recording
from skelfuse.fusion.engine import FusedFrame
from skelfuse.protocol.recording_file import Record, read_recording, write_recording
from skelfuse.recording.replay import calibration_of, replay
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings

SILENT = ("sim-1", 1.0, 4.5)
"""A sensor and the span of recorded seconds (from the start) it sends nothing in."""
BACK_S = 5.0
"""When its connection says hello again (seconds from the start)."""


def with_a_silence(source: Path, target: Path) -> Path:
    """``source`` with ``SILENT``'s sensor silent, then frames it sends while offline, then its
    ``hello`` again at ``BACK_S``; one frame of it sent twice (a replayed ``seq``)."""
    header, records = read_recording(source)
    t0 = records[0].t_server_ns
    sensor, quiet_from, quiet_to = SILENT
    hello = next(r for r in records if r.kind == "hello" and r.sensor_id == sensor)
    kept: list[Record] = []
    for record in records:
        t = (record.t_server_ns - t0) / 1e9
        if record.sensor_id == sensor and record.kind == "frame" and quiet_from < t < quiet_to:
            continue
        if kept and (kept[-1].t_server_ns - t0) / 1e9 < BACK_S <= t:
            kept.append(dataclasses.replace(hello, t_server_ns=t0 + round(BACK_S * 1e9) - 1))
        kept.append(record)
        if record.sensor_id == sensor and record.kind == "frame" and 0.5 < t < 0.55:
            kept.append(dataclasses.replace(record, t_server_ns=record.t_server_ns + 1))
    write_recording(target, header, kept)
    return target


def through_the_hub(path: Path) -> list[FusedFrame]:
    """Every record handed to a server hub as raw wire bytes, liveness checked every half
    heartbeat interval, the fusion step after each frame (the way replay ran before it fed the
    engine directly)."""
    header, records = read_recording(path)
    settings = Settings()
    offline = dataclasses.replace(
        settings,
        fusion=dataclasses.replace(
            settings.fusion,
            alignment=dataclasses.replace(settings.fusion.alignment, policy="aligned"),
        ),
    )
    hub = FusionHub(offline, calibration_of(header))
    every_s = offline.heartbeat_interval_s / 2
    t0 = records[0].t_server_ns / 1e9
    next_check = every_s
    fused: list[FusedFrame] = []
    for record in records:
        now_s = record.t_server_ns / 1e9
        while now_s - t0 >= next_check:
            hub.check_liveness(next_check)
            next_check += every_s
        hub.handle_message(record.sensor_id.encode(), [record.payload], now_s, now_s - t0)
        if record.kind == "frame" and (frame := hub.fuse_step(now_s)) is not None:
            fused.append(frame)
    return fused


def test_the_replay_engine_fuses_what_the_hub_fuses_across_a_silence(tmp_path: Path) -> None:
    source = tmp_path / "sim.sfrec"
    generate_recording(source, sensors=2, persons=1, duration_s=7.0, seed=5)
    path = with_a_silence(source, tmp_path / "silence.sfrec")
    engine = list(replay(path))
    hub = through_the_hub(path)
    assert len(engine) == len(hub) > 150
    sensor = SILENT[0]
    seen = [sensor in {v.sensor_id for v in f.raw} for f in engine]
    # the silence took it offline: unseen from it until the hello, seen again after
    t0 = engine[0].t_s
    assert not any(s for s, f in zip(seen, engine, strict=True) if 4.6 < f.t_s - t0 < BACK_S - 0.05)
    assert any(s for s, f in zip(seen, engine, strict=True) if f.t_s - t0 > BACK_S + 0.2)
    for ours, theirs in zip(engine, hub, strict=True):
        assert abs(ours.t_s - theirs.t_s) < 1e-9
        assert [v.sensor_id for v in ours.raw] == [v.sensor_id for v in theirs.raw]
        assert [p.person_id for p in ours.persons] == [p.person_id for p in theirs.persons]
        for a, b in zip(ours.persons, theirs.persons, strict=True):
            np.testing.assert_allclose(a.joints, b.joints, rtol=0, atol=1e-9)
