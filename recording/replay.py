"""Offline, deterministic fusion of a recording: the production :class:`FusionEngine` in
recorded time.

Every record is decoded and goes to a fresh engine (built with the recording's calibration) in
file order, with its recorded arrival time as "now": a ``hello`` registers its sensor, a frame
is buffered as the server's sessions (:class:`skelfuse.server.hub.FusionHub`) buffer an accepted
one; after each frame the fusion step runs at that time, as the live fusion loop does on every
arrival. Nothing reads the wall clock, so the same file always gives the same fused frames (and
the same bytes from :func:`write_jsonl`), as fast as the CPU allows.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TextIO

from skelfuse.calibration.store import Calibration, SensorCalibration, SpaceCalibration
from skelfuse.fusion.engine import FusedFrame, FusionEngine, warm_up
from skelfuse.fusion.settings import HubSettings
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.feed import frame_json
from skelfuse.protocol.recording_file import (
    SPACE_KEY_PREFIX,
    Header,
    ReadStatus,
    Record,
    RecordingReader,
)
from skelfuse.protocol.skeleton import skeleton_definition
from skelfuse.protocol.wire import Frame, Hello, decode


@dataclass(slots=True)
class ReplayStats:
    records: int = 0
    frames_in: int = 0
    fused_frames: int = 0
    first_t_s: float | None = None
    last_t_s: float | None = None
    read: ReadStatus | None = None
    warm_up_s: float = 0.0
    """Seconds spent compiling the fusion stages' loops (or loading numba's cache) before the
    first record (:func:`skelfuse.fusion.engine.warm_up`)."""

    @property
    def duration_s(self) -> float:
        if self.first_t_s is None or self.last_t_s is None:
            return 0.0
        return self.last_t_s - self.first_t_s


def calibration_of(header: Header) -> Calibration | None:
    """The recording's calibration as the engine takes it (None when nothing was calibrated): its
    sensors' stored poses, and its tracking spaces' (keys ``space:<id>``, moving sensors)."""
    stored = {key: pose for key, pose in header.calibration.items() if pose.state == "stored"}
    spaces = {
        key.removeprefix(SPACE_KEY_PREFIX): SpaceCalibration(pose.T_world_from_sensor, pose.method)
        for key, pose in stored.items()
        if key.startswith(SPACE_KEY_PREFIX)
    }
    sensors = {
        sensor_id: SensorCalibration(pose.T_world_from_sensor, pose.method, lag_s=pose.lag_s)
        for sensor_id, pose in stored.items()
        if not sensor_id.startswith(SPACE_KEY_PREFIX)
    }
    if not sensors and not spaces:
        return None
    return Calibration(0, header.created_unix_s, sensors, spaces=spaces)


def replay(
    path: str | Path,
    settings: HubSettings | None = None,
    *,
    stats: ReplayStats | None = None,
    strict: bool = False,
) -> Iterator[FusedFrame]:
    """Fused frames of a recording, in order, deterministically.

    Args:
        path: a ``.sfrec`` recording.
        settings: fusion settings (default: the server's defaults). The alignment is always
            ``aligned``: offline every sensor's frames are there, so waiting for all costs
            nothing, and a deadline (a wall-clock timer live) has no meaning.
        stats: filled in while replaying (records, frames, fused frames, time span).
        strict: refuse a truncated recording instead of replaying its readable part.

    Raises:
        RecordingError: the file is not a readable recording.
    """
    stats = stats if stats is not None else ReplayStats()
    started = time.perf_counter()
    warm_up()  # compile before the first frame, not inside one
    stats.warm_up_s = time.perf_counter() - started
    with RecordingReader(path, strict=strict) as reader:
        stats.read = reader.status
        settings = settings or HubSettings()
        offline = replace(
            settings,
            fusion=replace(
                settings.fusion, alignment=replace(settings.fusion.alignment, policy="aligned")
            ),
        )
        engine = FusionEngine(offline, calibration_of(reader.header))
        liveness_every_s = offline.heartbeat_interval_s / 2
        next_liveness: float | None = None
        t0: float | None = None
        for record in reader.records():
            now_s = record.t_server_ns / 1e9
            t0 = now_s if t0 is None else t0
            now_mono = now_s - t0
            stats.records += 1
            stats.first_t_s = now_s if stats.first_t_s is None else stats.first_t_s
            stats.last_t_s = now_s
            # The live server checks liveness on a timer; replay does it at the same cadence.
            if next_liveness is None:
                next_liveness = now_mono + liveness_every_s
            while now_mono >= next_liveness:
                engine.mark_silent_offline(next_liveness)
                next_liveness += liveness_every_s
            feed(engine, record, now_s, now_mono)
            if record.kind != "frame":
                continue
            stats.frames_in += 1
            fused = engine.fuse_step(now_s)
            if fused is not None:
                stats.fused_frames += 1
                yield fused


def feed(engine: FusionEngine, record: Record, now_s: float, now_mono: float) -> None:
    """Hand one recorded message to ``engine`` as the live server's sessions handled it when it
    arrived: a ``hello`` registers its sensor (the connection is named by the sensor id), a
    frame counts only from a sensor registered and online (one marked offline must say hello
    again, as live). What the server accepted decodes; anything else is skipped, as refused."""
    try:
        message = decode(record.payload)
    except DecodeError:
        return
    sensor = engine.sensors.get(record.sensor_id)
    if isinstance(message, Hello):
        engine.register(message, record.sensor_id.encode(), now_mono)
    elif isinstance(message, Frame) and sensor is not None and sensor.connected:
        sensor.last_heard_mono = now_mono  # heard: what the liveness check goes by
        engine.add_frame(sensor, message, now_s, now_mono)


def write_jsonl(frames: Iterable[FusedFrame], out: TextIO) -> int:
    """Write the skeleton definition, then one JSON line per fused frame; returns the count.

    Each line is the frame as apps get it on the WebSocket, minus the wall-clock ``t_sent``.
    """
    out.write(json.dumps(skeleton_definition(), separators=(",", ":")) + "\n")
    count = 0
    for frame in frames:
        out.write(
            json.dumps(frame_json(frame, include_raw=False), separators=(",", ":"), allow_nan=False)
        )
        out.write("\n")
        count += 1
    return count
