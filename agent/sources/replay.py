"""The ``replay`` source: one sensor of a skelfuse recording, played back live at recorded pace.

The agent then behaves as if that sensor were connected: it registers with the recorded sensor
type's frames (``sensor_type`` ``replay``), sends the recorded bodies and floor planes, and
stamps each frame with this PC's clock shifted so that the recorded spacing between frames is
kept exactly. The recorded calibration (or the recorded pose hint) becomes the pose hint. A
recorded moving sensor plays back as one: its hello's ``pose_space``, its frames' poses, and its
tracking space's recorded transform as its hint (docs/protocol.md §6.1).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from skelfuse.agent.sources.base import Capture, SensorError, wait_for_due
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.recording_file import SPACE_KEY_PREFIX, RecordingError, read_recording
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Frame, Hello, decode


class ReplaySource:
    """Plays the frames of ``sensor_id`` from ``path`` in real time (optionally looping).

    Raises:
        SensorError: the file is unreadable, or holds no (or several) sensors and none is named.
    """

    def __init__(
        self,
        path: str | Path,
        sensor_id: str | None = None,
        *,
        loop: bool = False,
        speed: float = 1.0,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        try:
            header, records = read_recording(path)
        except RecordingError as exc:
            raise SensorError(str(exc)) from exc
        sensors = sorted({r.sensor_id for r in records if r.kind == "frame"})
        if sensor_id is None:
            if len(sensors) != 1:
                raise SensorError(
                    f"{path}: holds sensors {', '.join(sensors) or '(none)'}; "
                    "choose one with --sensor"
                )
            sensor_id = sensors[0]
        if sensor_id not in sensors:
            raise SensorError(
                f"{path}: no frames from sensor {sensor_id!r} (it holds {', '.join(sensors)})"
            )
        if speed <= 0:
            raise SensorError(f"speed must be positive, got {speed}")
        self.sensor_id = sensor_id
        self._frames: list[Frame] = []
        self._hello: Hello | None = None
        for record in records:
            if record.sensor_id != sensor_id:
                continue
            try:
                message = decode(record.payload)
            except DecodeError as exc:
                raise SensorError(f"{path}: a recorded message does not decode: {exc}") from exc
            if isinstance(message, Frame):
                self._frames.append(message)
            elif isinstance(message, Hello) and self._hello is None:
                self._hello = message
        self.pose_space = self._hello.pose_space if self._hello and self._hello.moving else None
        """A recorded moving sensor's tracking space (None: a fixed sensor): the hello says
        ``moving`` and the frames keep their recorded poses."""
        self._pose: tuple[Matrix4, str] | None = None
        space = header.calibration.get(SPACE_KEY_PREFIX + (self.pose_space or ""))
        if self.pose_space is not None and space is not None:  # a moving sensor's hint: its space
            self._pose = space.T_world_from_sensor.copy(), "manual"
        elif sensor_id in header.calibration:
            self._pose = header.calibration[sensor_id].T_world_from_sensor.copy(), "manual"
        elif self._hello is not None and self._hello.pose_hint is not None:
            self._pose = (
                np.array(self._hello.pose_hint, dtype=np.float64),
                self._hello.pose_hint_source or "manual",
            )
        self._fps = self._hello.fps if self._hello is not None else 30.0
        self._loop = loop
        self._speed = speed
        self._clock = wall_clock_ns
        self._sleep = sleep
        self._index = 0
        self._anchor_ns: int | None = None
        self._first_ns = self._frames[0].t_capture_ns
        self._span_ns = self._frames[-1].t_capture_ns - self._first_ns + round(1e9 / self._fps)

    waits_for_server = True
    """The runner starts playback once the server has registered this agent."""

    @property
    def sensor_type(self) -> str:
        return "replay"

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def frame_count(self) -> int:
        return len(self._frames)

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None if self._pose is None else (self._pose[0].copy(), self._pose[1])

    def next_capture(self, timeout_s: float) -> Capture | None:
        if self._index >= len(self._frames):
            if not self._loop:
                self._sleep(timeout_s)
                return None
            self._index = 0
            assert self._anchor_ns is not None
            self._anchor_ns += round(self._span_ns / self._speed)
        frame = self._frames[self._index]
        now = self._clock()
        if self._anchor_ns is None:
            self._anchor_ns = now
        due = self._anchor_ns + round((frame.t_capture_ns - self._first_ns) / self._speed)
        if not wait_for_due(due, now, timeout_s, self._sleep):
            return None
        self._index += 1
        return Capture(t_capture_ns=due, bodies=frame.bodies, floor=frame.floor, pose=frame.pose)

    def close(self) -> None:
        return None
