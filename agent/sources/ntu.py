"""NTU RGB+D ``.skeleton`` files (Kinect v2, 30 fps): a reader and the ``ntu`` source.

The format (text, whitespace-separated; full description in ``docs/recording.md``)::

    <frame count>
    per frame:  <body count>
      per body: bodyID clipedEdges handLeftConfidence handLeftState handRightConfidence
                handRightState isResticted leanX leanY trackingState
                <joint count = 25>
                per joint: x y z depthX depthY colorX colorY
                           orientationW orientationX orientationY orientationZ trackingState

x, y, z are Kinect v2 camera space (metres, +X sensor-left, +Y up, +Z forward: our sensor
frame as is); joints come in ``JointType`` order, so no mapping is needed. The files have no
timestamps: frame i is at i/30 s. The cameras' poses are not in the files: fusing the three
cameras of a performance needs each sensor's pose (``--pose``) or a calibration.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skelfuse.agent.sources.base import Capture, SensorError
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body

NTU_FPS = 30.0
_NAME = re.compile(r"S(\d{3})C(\d{3})P(\d{3})R(\d{3})A(\d{3})")


class NtuFormatError(SensorError):
    """A ``.skeleton`` file that does not follow the format; the message gives the line."""


@dataclass(frozen=True, slots=True)
class NtuName:
    """What an NTU file name (``S001C002P003R002A013``) says: setup, camera, performer,
    replication, action."""

    setup: int
    camera: int
    performer: int
    replication: int
    action: int

    @property
    def performance(self) -> str:
        """The key shared by the three cameras of one performance (camera left out)."""
        return f"S{self.setup:03d}P{self.performer:03d}R{self.replication:03d}A{self.action:03d}"


def parse_ntu_name(path: str | Path) -> NtuName | None:
    match = _NAME.search(Path(path).name)
    return None if match is None else NtuName(*(int(g) for g in match.groups()))


def read_ntu_skeleton(path: str | Path) -> list[tuple[Body, ...]]:
    """Every frame's bodies (sensor frame, metres; tracking id = NTU bodyID).

    Raises:
        NtuFormatError: with the line number where the file stops making sense.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="ascii", errors="replace").split("\n")
    except OSError as exc:
        raise NtuFormatError(f"{path}: cannot read ({exc.strerror})") from exc
    position = 0

    def line() -> list[str]:
        nonlocal position
        while position < len(lines) and not lines[position].strip():
            position += 1
        if position >= len(lines):
            raise NtuFormatError(f"{path}: ends early at line {position + 1}")
        position += 1
        return lines[position - 1].split()

    def integer(fields: list[str], what: str) -> int:
        try:
            return int(fields[0])
        except (IndexError, ValueError) as exc:
            raise NtuFormatError(f"{path}:{position}: expected {what}, got {fields!r}") from exc

    frames: list[tuple[Body, ...]] = []
    frame_count = integer(line(), "the frame count")
    for _ in range(frame_count):
        bodies = []
        for _ in range(integer(line(), "a body count")):
            info = line()
            if len(info) != 10:
                raise NtuFormatError(f"{path}:{position}: a body line has 10 values, got {info}")
            body_id = integer(info, "a bodyID")
            count = integer(line(), "the joint count")
            if count != JOINT_COUNT:
                raise NtuFormatError(f"{path}:{position}: {count} joints (expected 25)")
            joints = np.zeros((JOINT_COUNT, 3), dtype=np.float32)
            states = np.zeros(JOINT_COUNT, dtype=np.uint8)
            for j in range(JOINT_COUNT):
                values = line()
                if len(values) != 12:
                    raise NtuFormatError(f"{path}:{position}: a joint line has 12 values")
                try:
                    joints[j] = [float(v) for v in values[:3]]
                    state = int(values[11])
                except ValueError as exc:
                    raise NtuFormatError(f"{path}:{position}: not numbers: {values}") from exc
                states[j] = min(max(state, 0), 2)
            joints[~np.isfinite(joints).all(axis=1)] = np.nan
            states[~np.isfinite(joints).all(axis=1)] = 0
            bodies.append(Body(body_id % 2**64, joints, states))
        frames.append(tuple(bodies))
    return frames


class NtuSource:
    """Plays an NTU ``.skeleton`` file as a live Kinect v2 at 30 fps.

    Args:
        path: the file.
        pose: ``T_world_from_sensor`` to announce as a manual pose hint (NTU files carry none).
        loop: start again after the last frame.
        start_unix_s: wall-clock instant of frame 0; give the three cameras of one performance
            the same value so their frames line up (default: when the first frame is read).
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
        self.frames = read_ntu_skeleton(path)
        if not self.frames:
            raise NtuFormatError(f"{path}: no frames")
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
        wait_s = (due - now) / 1e9
        if wait_s > timeout_s:
            self._sleep(timeout_s)
            return None
        if wait_s > 0:
            self._sleep(wait_s)
        bodies = self.frames[self._index % len(self.frames)]
        self._index += 1
        return Capture(t_capture_ns=due, bodies=bodies)

    def close(self) -> None:
        return None
