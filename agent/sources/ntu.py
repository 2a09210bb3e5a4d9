"""The ``ntu`` source: an NTU RGB+D ``.skeleton`` file played as a live Kinect v2 at 30 fps.

The file format and its reader are in :mod:`skelfuse.protocol.ntu`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from skelfuse.agent.sources.base import Capture, SensorError, wait_for_due
from skelfuse.protocol.ntu import NTU_FPS, NtuFormatError, read_ntu_skeleton
from skelfuse.protocol.transform import Matrix4


class NtuSource:
    """Plays an NTU ``.skeleton`` file as a live Kinect v2 at 30 fps.

    Args:
        path: the file.
        pose: ``T_world_from_sensor`` to announce as a manual pose hint (NTU files carry none).
        loop: start again after the last frame.
        start_unix_s: wall-clock instant of frame 0; give the three cameras of one performance
            the same value so their frames line up (default: when the first frame is read).

    Raises:
        SensorError: the file is unreadable, does not follow the format, or holds no frames.
    """

    def __init__(
        self,
        path: str | Path,
        pose: Matrix4 | None = None,
        *,
        loop: bool = False,
        start_unix_s: float | None = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        try:
            self.frames = read_ntu_skeleton(path)
        except NtuFormatError as exc:
            raise SensorError(str(exc)) from exc
        if not self.frames:
            raise SensorError(f"{path}: no frames")
        self._pose = pose
        self._loop = loop
        self._clock = wall_clock_ns
        self._sleep = sleep
        self._period_ns = round(1e9 / NTU_FPS)
        self._start_ns = None if start_unix_s is None else round(start_unix_s * 1e9)
        self._index = 0

    @property
    def sensor_type(self) -> str:
        return "kinect_v2"

    @property
    def fps(self) -> float:
        return NTU_FPS

    def pose_hint(self) -> tuple[Matrix4, str] | None:
        return None if self._pose is None else (self._pose.copy(), "manual")

    def next_capture(self, timeout_s: float) -> Capture | None:
        now = self._clock()
        if self._start_ns is None:
            self._start_ns = now
        if self._index >= len(self.frames) and not self._loop:
            self._sleep(timeout_s)
            return None
        due = self._start_ns + self._index * self._period_ns
        if not wait_for_due(due, now, timeout_s, self._sleep):
            return None
        bodies = self.frames[self._index % len(self.frames)]
        self._index += 1
        return Capture(t_capture_ns=due, bodies=bodies)

    def close(self) -> None:
        return None
