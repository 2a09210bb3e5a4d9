"""What the server knows about each sensor: session, health counters, clock offset, frames.

Clock assumption (protocol v1): an agent stamps ``t_capture_ns`` with its own wall clock, which
may be off by any amount. The server maps it onto its own clock with an offset estimated as the
minimum, over the last :data:`OFFSET_WINDOW_S`, of (server receive time − capture stamp): the
frame that arrived fastest bounds the offset, and the minimum network + processing delay it
includes is assumed small and equal across agents (sub-millisecond on a LAN). Offsets that
drift are followed as the window slides. A later protocol version measures round trips instead.
"""

from __future__ import annotations

from bisect import bisect_left
from collections import Counter, deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from protocol.skeleton import TrackingState
from protocol.transform import Matrix4
from protocol.wire import Body, Frame, Hello

OFFSET_WINDOW_S = 10.0
FRAME_BUFFER_S = 1.0


class SlidingMinimum:
    """Minimum of the values seen in the last ``window`` time units (monotonic deque)."""

    def __init__(self, window: float) -> None:
        self._window = window
        self._items: deque[tuple[float, float]] = deque()

    def push(self, t: float, value: float) -> float:
        while self._items and self._items[-1][1] >= value:
            self._items.pop()
        self._items.append((t, value))
        while self._items[0][0] < t - self._window:
            self._items.popleft()
        return self._items[0][1]


@dataclass(slots=True)
class TimedFrame:
    """A frame with its capture time on the server's clock (Unix seconds)."""

    t_server_s: float
    frame: Frame


@dataclass(slots=True)
class SensorState:
    sensor_id: str
    sensor_type: str
    agent_version: str
    routing_id: bytes
    nominal_fps: float
    pose_hint: Matrix4 | None = None
    pose_hint_source: str | None = None
    connected: bool = True
    last_heard_mono: float = 0.0
    last_frame_mono: float | None = None
    frames_received: int = 0
    frames_rejected: Counter[str] = field(default_factory=Counter)
    sequence_gaps: int = 0
    last_seq: int | None = None
    bodies_last: int = 0
    clock_offset_s: float | None = None
    frames: deque[TimedFrame] = field(default_factory=deque)
    _arrivals: deque[float] = field(default_factory=deque)
    _offset: SlidingMinimum = field(default_factory=lambda: SlidingMinimum(OFFSET_WINDOW_S))

    def add_frame(self, frame: Frame, received_s: float, received_mono: float) -> TimedFrame:
        """Record a frame received at ``received_s`` (server wall clock, Unix seconds)."""
        capture_s = frame.t_capture_ns / 1e9
        if self.last_seq is not None and frame.seq > self.last_seq + 1:
            self.sequence_gaps += frame.seq - self.last_seq - 1
        self.last_seq = frame.seq
        self.clock_offset_s = self._offset.push(received_s, received_s - capture_s)
        timed = TimedFrame(capture_s + self.clock_offset_s, frame)
        # Frames arrive in capture order on one connection; keep the buffer sorted anyway.
        if self.frames and timed.t_server_s < self.frames[-1].t_server_s:
            items = list(self.frames)
            items.insert(bisect_left([f.t_server_s for f in items], timed.t_server_s), timed)
            self.frames = deque(items)
        else:
            self.frames.append(timed)
        while self.frames and self.frames[0].t_server_s < timed.t_server_s - FRAME_BUFFER_S:
            self.frames.popleft()
        self.frames_received += 1
        self.bodies_last = len(frame.bodies)
        self.last_frame_mono = received_mono
        self._arrivals.append(received_mono)
        while self._arrivals and self._arrivals[0] < received_mono - 2.0:
            self._arrivals.popleft()
        return timed

    def fps(self, now_mono: float) -> float:
        recent = [t for t in self._arrivals if t >= now_mono - 2.0]
        if len(recent) < 2:
            return 0.0
        span = max(recent[-1] - recent[0], 1e-6)
        return (len(recent) - 1) / span

    def latest_time(self) -> float | None:
        return self.frames[-1].t_server_s if self.frames else None


def new_sensor(hello: Hello, routing_id: bytes, now_mono: float) -> SensorState:
    return SensorState(
        sensor_id=hello.sensor_id,
        sensor_type=hello.sensor_type,
        agent_version=hello.agent_version,
        routing_id=routing_id,
        nominal_fps=hello.fps,
        pose_hint=hello.pose_hint,
        pose_hint_source=hello.pose_hint_source,
        last_heard_mono=now_mono,
    )


# --- alignment: a sensor's bodies at an arbitrary instant --------------------------------------


def bodies_at(
    frames: deque[TimedFrame] | list[TimedFrame],
    t_s: float,
    max_gap_s: float,
    max_age_s: float,
) -> tuple[Body, ...] | None:
    """The sensor's bodies at server time ``t_s``, interpolated between the two frames around it.

    A body present in both frames (same tracking id) is interpolated linearly joint by joint,
    taking the lower of the two tracking states; a body in only one of them, or frames more than
    ``max_gap_s`` apart, give the nearer frame's bodies. After the newest frame, that frame is
    used for ``max_age_s`` (no extrapolation); None when the sensor has nothing usable.
    """
    if not frames:
        return None
    times = [f.t_server_s for f in frames]
    index = bisect_left(times, t_s)
    if index == len(frames):
        newest = frames[-1]
        return newest.frame.bodies if t_s - newest.t_server_s <= max_age_s else None
    after = frames[index]
    if after.t_server_s == t_s or index == 0:
        return after.frame.bodies if after.t_server_s - t_s <= max_age_s else None
    before = frames[index - 1]
    gap = after.t_server_s - before.t_server_s
    alpha = (t_s - before.t_server_s) / gap if gap > 0 else 1.0
    if gap > max_gap_s:
        nearest = after if alpha >= 0.5 else before
        return nearest.frame.bodies if abs(nearest.t_server_s - t_s) <= max_age_s else None
    earlier = {b.tracking_id: b for b in before.frame.bodies}
    nearer = after.frame.bodies if alpha >= 0.5 else before.frame.bodies
    if alpha < 0.5:
        later = {b.tracking_id: b for b in after.frame.bodies}
        return tuple(
            _lerp_body(b, later[b.tracking_id], alpha) if b.tracking_id in later else b
            for b in nearer
        )
    return tuple(
        _lerp_body(earlier[b.tracking_id], b, alpha) if b.tracking_id in earlier else b
        for b in nearer
    )


def _lerp_body(first: Body, second: Body, alpha: float) -> Body:
    a = first.joints_m.astype(np.float64)
    b = second.joints_m.astype(np.float64)
    joints = (1.0 - alpha) * a + alpha * b
    both = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    # Where only one frame has the joint, the nearer frame decides.
    nearer = b if alpha >= 0.5 else a
    joints[~both] = nearer[~both]
    states: npt.NDArray[np.uint8] = np.minimum(first.states, second.states)
    nearer_states = second.states if alpha >= 0.5 else first.states
    states[~both] = nearer_states[~both]
    states[~np.isfinite(joints).all(axis=1)] = TrackingState.NOT_TRACKED
    tracking_id = second.tracking_id if alpha >= 0.5 else first.tracking_id
    return Body(tracking_id, joints.astype(np.float32), states)
