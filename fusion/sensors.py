"""What the server knows about each sensor: session, health counters, clock offset, frames.

Clocks: an agent stamps ``t_capture_ns`` with its own wall clock, which may be off by seconds
and drift. The server maps stamps onto its own clock with an offset it measures itself:

- **Round trip (NTP-style), preferred.** The server's heartbeats carry its clock; the agent
  echoes the stamp at once with its own clock (``echo_ns``). Each echo gives a round-trip time
  and an offset sample ``server − agent = (t_sent + rtt/2) − t_agent``; the sample with the
  smallest round trip in the last :data:`OFFSET_WINDOW_S` wins (its error is at most rtt/2), as
  in NTP and LSL. To follow drift, a line is fitted through the quickest third of the samples
  and read at the present; a clock step (three samples in a row 100 ms off) restarts the
  window.
- **One way, until the first echo.** The minimum over the window of (receive time − capture
  stamp): it assumes the fastest frame's delay is small and alike across agents.

A sensor may also show events late on its own clock (a camera whose stamps are taken after
exposure, a video's start guessed): the calibration's ``lag_s`` (:mod:`calibration.motion_sync`)
is subtracted from its mapped times (:meth:`SensorState.use_lag`; 0 when none is stored).

Frames whose mapped capture time is more than :data:`STALE_S` old on arrival (a backlog after an
outage) or :data:`FUTURE_S` in the future (a clock jump, a replayed recording) are rejected.

A moving sensor (a depth camera on a headset, ``hello.moving``; section "Moving sensors") sends
its bodies in its own camera frame, which moves, with the frame's pose ``T_space_from_sensor``
at the capture instant (docs/protocol.md §6.3). The server places every such frame in the
sensor's tracking space as it arrives (:func:`placed_in_space`): from then on the sensor's "own
frame" is the space, which does not move, so everything downstream treats it like a fixed sensor
whose pose is the space's ``T_world_from_space`` (:mod:`skelfuse.fusion.spaces`): time
interpolation between frames (of bodies that moved in the space, not in a turning camera),
association, filters, and the calibration solvers that work on a sensor's bodies. What stays the
sensor's own is where it is: each placed frame keeps its pose, and :func:`world_position` gives
the sensor's origin in the world at any instant between frames (the mirror labels and the ray
weighting look from there), interpolated by the rule agents use
(:func:`skelfuse.protocol.sensor_pose.interpolate_pose`).

What ``GET /api/sensors`` shows of them (last section, :func:`sensor_rows`): one JSON-ready row
per known sensor, its session, health counters, clock, calibration and drift.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import numpy as np
import numpy.typing as npt

from skelfuse.calibration.store import Calibration
from skelfuse.fusion.drift import DriftMonitor
from skelfuse.fusion.points import finite_points
from skelfuse.protocol.hands import Hands
from skelfuse.protocol.messages import checked_body, checked_frame
from skelfuse.protocol.sensor_pose import interpolate_pose, pose_matrix
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4
from skelfuse.protocol.wire import Body, Frame, Hello, SensorPose

OFFSET_WINDOW_S = 10.0
FRAME_BUFFER_S = 1.0
STALE_S = 0.5
FUTURE_S = 0.5
MAX_RTT_S = 2.0
STEP_S = 0.1


class RoundTripOffset:
    """Clock offset (server − agent, seconds) from echoed heartbeats, minimum round trip wins."""

    def __init__(self, window_s: float = OFFSET_WINDOW_S) -> None:
        self._window = window_s
        self._samples: deque[tuple[float, float, float]] = deque()  # (received, rtt, offset)
        self._disagreeing = 0
        self.offset_s: float | None = None
        self.rtt_s: float | None = None

    def add(self, sent_server_s: float, agent_s: float, received_server_s: float) -> None:
        rtt = received_server_s - sent_server_s
        if not 0.0 <= rtt <= MAX_RTT_S:
            return  # not an echo of ours, or hopelessly late
        offset = sent_server_s + rtt / 2.0 - agent_s
        if self.offset_s is not None and abs(offset - self.offset_s) > STEP_S + rtt:
            self._disagreeing += 1
            if self._disagreeing >= 3:  # the agent's clock stepped: start over
                self._samples.clear()
        else:
            self._disagreeing = 0
        self._samples.append((received_server_s, rtt, offset))
        while self._samples and self._samples[0][0] < received_server_s - self._window:
            self._samples.popleft()
        _, self.rtt_s, best = min(self._samples, key=lambda s: s[1])
        # Drift: fit a line through the quickest third of the samples (their delays are the
        # most symmetric) and read it at "now"; with too few, the quickest sample stands.
        ranked = sorted(self._samples, key=lambda s: s[1])
        quick = sorted(ranked[: max(4, len(ranked) // 3)])
        span = quick[-1][0] - quick[0][0]
        if len(quick) >= 4 and span >= 2.0:
            times = np.array([t for t, _, _ in quick]) - received_server_s
            offsets = np.array([o for _, _, o in quick])
            # A sample's error is at most half its round trip: weigh by 1/rtt (polyfit squares).
            weights = 1.0 / np.maximum(np.array([r for _, r, _ in quick]), 1e-5)
            _, intercept = np.polyfit(times, offsets, 1, w=weights)
            self.offset_s = float(intercept)
        else:
            self.offset_s = best


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


class BodyArrays(NamedTuple):
    """A sensor's bodies at one instant, stacked (one array operation serves them all).

    tracking_ids: B ids, in the frame's order; joints_m: (B, 25, 3) float32, metres, the
    sensor's own frame, NaN where unknown; states: (B, 25) uint8 TrackingState; hands: B hand
    states (None where a body has none), or None when no body has any (the usual case).
    """

    tracking_ids: list[int]
    joints_m: npt.NDArray[np.float32]
    states: npt.NDArray[np.uint8]
    hands: list[Hands | None] | None = None


@dataclass(slots=True)
class TimedFrame:
    """A frame with its capture time on the server's clock (Unix seconds)."""

    t_server_s: float
    frame: Frame
    _arrays: BodyArrays | None = field(default=None, repr=False, compare=False)

    def arrays(self) -> BodyArrays:
        """The frame's bodies stacked on first use (a frame serves ~2 fused instants): the
        decoder's arrays (``Frame.stacked``, the bodies' rows: no copy) when it left them."""
        if self._arrays is None:
            bodies = self.frame.bodies
            stacked = self.frame.stacked
            if stacked is not None:
                joints, states = stacked
            elif bodies:
                joints = np.array([b.joints_m for b in bodies])  # np.stack's result, 3× faster
                states = np.array([b.states for b in bodies])
            else:
                joints = np.empty((0, JOINT_COUNT, 3), np.float32)
                states = np.empty((0, JOINT_COUNT), np.uint8)
            hands = [b.hands for b in bodies]
            self._arrays = BodyArrays(
                [b.tracking_id for b in bodies],
                joints,
                states,
                hands if any(h is not None for h in hands) else None,
            )
        return self._arrays


@dataclass(slots=True)
class SensorState:
    sensor_id: str
    sensor_type: str
    agent_version: str
    routing_id: bytes
    nominal_fps: float
    pose_hint: Matrix4 | None = None
    pose_hint_source: str | None = None
    moving: bool = False
    """Head-mounted or otherwise moving: frames are placed in ``pose_space`` as they arrive
    (:func:`placed_in_space`), so ``frames`` hold bodies in the space, not the sensor."""
    pose_space: str | None = None
    connected: bool = True
    last_heard_mono: float = 0.0
    last_frame_mono: float | None = None
    frames_received: int = 0
    frames_rejected: Counter[str] = field(default_factory=Counter)
    sequence_gaps: int = 0
    last_seq: int | None = None
    bodies_last: int = 0
    clock_offset_s: float | None = None
    clock_source: str = "none"
    lag_s: float = 0.0
    round_trip: RoundTripOffset = field(default_factory=RoundTripOffset)
    frames: deque[TimedFrame] = field(default_factory=deque)
    _arrivals: deque[float] = field(default_factory=deque)
    _offset: SlidingMinimum = field(default_factory=lambda: SlidingMinimum(OFFSET_WINDOW_S))

    def frame_time_problem(self, frame: Frame, received_s: float) -> str | None:
        """``stale`` or ``future`` when the frame's mapped capture time is implausible;
        ``no_pose`` for a moving sensor's frame without a pose (it cannot be placed)."""
        if self.moving and frame.pose is None:
            return NO_POSE
        offset = self.round_trip.offset_s
        if offset is None:
            offset = self.clock_offset_s
        if offset is None:
            return None
        capture_server_s = frame.t_capture_ns / 1e9 + offset - self.lag_s
        if capture_server_s < received_s - STALE_S:
            return "stale"
        if capture_server_s > received_s + FUTURE_S:
            return "future"
        return None

    def admit(self, frame: Frame, received_s: float) -> str | None:
        """Note a delivered frame's ``seq``, then say why it is rejected
        (:meth:`frame_time_problem`) or None. A frame rejected for what it holds is counted once,
        in ``frames_rejected``: its seq was seen, so the next frame does not count it again as a
        sequence gap (frames numbered but never delivered, docs/protocol.md §10.5)."""
        self._note_seq(frame.seq)
        return self.frame_time_problem(frame, received_s)

    def _note_seq(self, seq: int) -> None:
        if self.last_seq is not None and seq > self.last_seq + 1:
            self.sequence_gaps += seq - self.last_seq - 1
        self.last_seq = seq

    def keep_clock_of(self, previous: SensorState) -> None:
        """Take over ``previous``'s clock estimates (round trip, one-way minimum, offset): the
        same agent on the same connection registered again, so its clock has not changed."""
        self.round_trip = previous.round_trip
        self._offset = previous._offset
        self.clock_offset_s = previous.clock_offset_s
        self.clock_source = previous.clock_source

    def use_lag(self, lag_s: float) -> None:
        """Place this sensor's frames ``lag_s`` seconds before their mapped stamps (its clock
        lag) from now on, and move the frames already buffered by the change, so a new
        calibration shifts the sensor's whole timeline at once instead of leaving a jump (or a
        reversal) inside its buffer."""
        shift = self.lag_s - lag_s
        if shift:
            for timed in self.frames:
                timed.t_server_s += shift
        self.lag_s = lag_s

    def add_frame(self, frame: Frame, received_s: float, received_mono: float) -> TimedFrame:
        """Record a frame received at ``received_s`` (server wall clock, Unix seconds); a moving
        sensor's is kept placed in its tracking space (its pose is checked before)."""
        if self.moving:
            frame = placed_in_space(frame)
        capture_s = frame.t_capture_ns / 1e9
        self._note_seq(frame.seq)
        one_way = self._offset.push(received_s, received_s - capture_s)
        if self.round_trip.offset_s is not None:
            self.clock_offset_s, self.clock_source = self.round_trip.offset_s, "round_trip"
        else:
            self.clock_offset_s, self.clock_source = one_way, "one_way"
        timed = TimedFrame(capture_s + self.clock_offset_s - self.lag_s, frame)
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


def calibrated_lag_s(calibration: Calibration | None, sensor_id: str) -> float:
    """The clock lag ``calibration`` stores for ``sensor_id`` (seconds; 0 when it has none)."""
    entry = None if calibration is None else calibration.sensors.get(sensor_id)
    return 0.0 if entry is None or entry.lag_s is None else entry.lag_s


def new_sensor(hello: Hello, routing_id: bytes, now_mono: float) -> SensorState:
    return SensorState(
        sensor_id=hello.sensor_id,
        sensor_type=hello.sensor_type,
        agent_version=hello.agent_version,
        routing_id=routing_id,
        nominal_fps=hello.fps,
        pose_hint=hello.pose_hint,
        pose_hint_source=hello.pose_hint_source,
        moving=hello.moving,
        pose_space=hello.pose_space,
        last_heard_mono=now_mono,
    )


# --- alignment: a sensor's bodies at an arbitrary instant ----------------------------------------


def bodies_at(
    frames: deque[TimedFrame] | list[TimedFrame],
    t_s: float,
    max_gap_s: float,
    max_age_s: float,
) -> tuple[Body, ...] | None:
    """:func:`body_arrays_at` as one :class:`~protocol.wire.Body` per body."""
    arrays = body_arrays_at(frames, t_s, max_gap_s, max_age_s)
    if arrays is None:
        return None
    hands = arrays.hands or [None] * len(arrays.tracking_ids)
    return tuple(map(Body, arrays.tracking_ids, arrays.joints_m, arrays.states, hands))


def body_arrays_at(
    frames: deque[TimedFrame] | list[TimedFrame],
    t_s: float,
    max_gap_s: float,
    max_age_s: float,
) -> BodyArrays | None:
    """The sensor's bodies at server time ``t_s``, interpolated between the two frames around it.

    A body present in both frames (same tracking id) is interpolated linearly joint by joint,
    taking the lower of the two tracking states (hand states: the nearer frame's); a body in only
    one of them, or frames more than ``max_gap_s`` apart, give the nearer frame's bodies, in the
    nearer frame's order. After the
    newest frame, that frame is used for ``max_age_s`` (no extrapolation); None when the sensor
    has nothing usable. All of a frame's bodies are interpolated at once.
    """
    if not frames:
        return None
    # bisect_left over the frames' times, from the newest: the instant is near the end.
    index = len(frames)
    while index > 0 and frames[index - 1].t_server_s >= t_s:
        index -= 1
    if index == len(frames):
        newest = frames[-1]
        return newest.arrays() if t_s - newest.t_server_s <= max_age_s else None
    after = frames[index]
    if after.t_server_s == t_s or index == 0:
        return after.arrays() if after.t_server_s - t_s <= max_age_s else None
    before = frames[index - 1]
    gap = after.t_server_s - before.t_server_s
    alpha = (t_s - before.t_server_s) / gap if gap > 0 else 1.0
    if gap > max_gap_s:
        nearest = after if alpha >= 0.5 else before
        return nearest.arrays() if abs(nearest.t_server_s - t_s) <= max_age_s else None
    later = alpha >= 0.5
    nearer_frame, other_frame = (after, before) if later else (before, after)
    nearer, other = nearer_frame.arrays(), other_frame.arrays()
    index_of = {tracking_id: i for i, tracking_id in enumerate(other.tracking_ids)}
    mine = [i for i, tracking_id in enumerate(nearer.tracking_ids) if tracking_id in index_of]
    if not mine:
        return nearer
    theirs = [index_of[nearer.tracking_ids[i]] for i in mine]
    everyone = len(mine) == len(nearer.tracking_ids)
    if everyone:  # every body in both frames (the usual case)
        near_joints, near_states = nearer.joints_m, nearer.states
    else:
        near_joints, near_states = nearer.joints_m[mine], nearer.states[mine]
    if theirs == list(range(len(other.tracking_ids))):  # the same bodies in the same order
        far_joints, far_states = other.joints_m, other.states
    else:
        far_joints, far_states = other.joints_m[theirs], other.states[theirs]
    if later:
        joints, states = _lerp(far_joints, far_states, near_joints, near_states, alpha)
    else:
        joints, states = _lerp(near_joints, near_states, far_joints, far_states, alpha)
    if everyone:
        return BodyArrays(nearer.tracking_ids, joints, states, nearer.hands)
    all_joints, all_states = nearer.joints_m.copy(), nearer.states.copy()
    all_joints[mine] = joints
    all_states[mine] = states
    return BodyArrays(nearer.tracking_ids, all_joints, all_states, nearer.hands)


def _lerp(
    first_joints: npt.NDArray[np.float32],
    first_states: npt.NDArray[np.uint8],
    second_joints: npt.NDArray[np.float32],
    second_states: npt.NDArray[np.uint8],
    alpha: float,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """(B, 25, 3) joints and (B, 25) states a fraction ``alpha`` of the way from first to second.

    Element by element (the same floats for one body or many): float64 arithmetic, float32 out;
    where only one frame has a joint, the nearer frame decides; the lower tracking state wins.
    """
    a = first_joints.astype(np.float64)
    b = second_joints.astype(np.float64)
    joints = (1.0 - alpha) * a + alpha * b
    states: npt.NDArray[np.uint8] = np.minimum(first_states, second_states)
    # The sum is finite only if every interpolated position is, hence every position of both
    # frames (NaN and inf propagate): one cheap check for the usual case, nothing to patch.
    if math.isfinite(joints.sum()):
        return joints.astype(np.float32), states
    both = finite_points(a) & finite_points(b)
    # Where only one frame has the joint, the nearer frame decides.
    nearer = b if alpha >= 0.5 else a
    joints[~both] = nearer[~both]
    nearer_states = second_states if alpha >= 0.5 else first_states
    states[~both] = nearer_states[~both]
    states[~finite_points(joints)] = TrackingState.NOT_TRACKED
    return joints.astype(np.float32), states


# --- Moving sensors: frames placed in their tracking space, and where the sensor is --------------


FloatArray = npt.NDArray[np.float64]


class TimedPose(Protocol):
    """A frame at its time on the server's clock (:class:`skelfuse.fusion.sensors.TimedFrame`,
    which imports this module)."""

    t_server_s: float
    frame: Frame


NO_POSE = "no_pose"
"""The rejection reason of a moving sensor's frame that carries no pose (it cannot be placed)."""


def placed_in_space(frame: Frame) -> Frame:
    """``frame`` with its bodies and floor moved from the sensor's frame into its tracking space
    by the frame's own pose (``T_space_from_sensor``); the pose is kept.

    Joints (25, 3) float32 metres, computed in float64 (NaN stays NaN); the floor plane
    ``a·x + b·y + c·z + d = 0`` keeps a unit normal.

    Raises:
        ValueError: the frame has no pose.
    """
    if frame.pose is None:
        raise ValueError("a frame without a pose cannot be placed in a tracking space")
    transform = pose_matrix(frame.pose)
    rotation_t, shift = transform[:3, :3].T, transform[:3, 3]
    bodies = frame.bodies
    if bodies:
        joints = np.array([body.joints_m for body in bodies], dtype=np.float64)
        placed = (joints @ rotation_t + shift).astype(np.float32)
        bodies = tuple(map(_moved, bodies, placed))
    floor = frame.floor
    if floor is not None:
        normal = transform[:3, :3] @ np.asarray(floor[:3], dtype=np.float64)
        a, b, c = (float(v) for v in normal)
        floor = (a, b, c, float(floor[3] - normal @ shift))
    return checked_frame(frame.seq, frame.t_capture_ns, bodies, floor, frame.pose)


def _moved(body: Body, joints_m: npt.NDArray[np.float32]) -> Body:
    return checked_body(body.tracking_id, joints_m, body.states, body.hands)


def position_in_space(frames: Sequence[TimedPose], t_s: float) -> tuple[float, float, float] | None:
    """Where a moving sensor's origin is in its space at ``t_s`` (metres), by
    :func:`sensor_pose_at`'s rule; None without a posed frame."""
    pose = sensor_pose_at(frames, t_s)
    return None if pose is None else pose.position_m


def world_position(
    frames: Sequence[TimedPose], t_s: float, world_from_space: Matrix4
) -> FloatArray | None:
    """A moving sensor's origin in the world at ``t_s``: (3,) float64 metres, or None when no
    frame says where it is."""
    origin = position_in_space(frames, t_s)
    if origin is None:
        return None
    moved: FloatArray = world_from_space[:3, :3] @ np.asarray(origin) + world_from_space[:3, 3]
    return moved


def sensor_pose_at(frames: Sequence[TimedPose], t_s: float) -> SensorPose | None:
    """A moving sensor's pose in its space at server time ``t_s``: interpolated between the two
    frames around it (position linear, rotation slerp), before the first or after the newest
    held at that frame's (its bodies are held the same way); None without a posed frame."""
    if not frames:
        return None
    index = len(frames)
    while index > 0 and frames[index - 1].t_server_s >= t_s:
        index -= 1
    if index == len(frames) or index == 0:
        return frames[-1 if index else 0].frame.pose
    before, after = frames[index - 1], frames[index]
    first, second = before.frame.pose, after.frame.pose
    if first is None or second is None:
        return first or second
    gap = after.t_server_s - before.t_server_s
    return interpolate_pose(first, second, (t_s - before.t_server_s) / gap if gap > 0 else 1.0)


# --- The sensors table of GET /api/sensors: one JSON-ready row per known sensor ------------------


def sensor_rows(
    sensors: Iterable[SensorState],
    pose_of: Callable[[str], tuple[Matrix4 | None, str]],
    drift: DriftMonitor | None,
    now_mono: float,
) -> list[dict[str, object]]:
    """Session, health counters, clock, calibration and drift of each sensor, sorted by id.

    ``pose_of`` gives a sensor's ``T_world_from_sensor`` and where it comes from (the engine's
    :meth:`~skelfuse.fusion.engine.FusionEngine.pose_of`; a moving sensor's is its tracking
    space's, and its row names the space: ``pose_space``); ``now_mono``: monotonic seconds.
    """
    rows: list[dict[str, object]] = []
    for sensor in sorted(sensors, key=lambda x: x.sensor_id):
        pose, state = pose_of(sensor.sensor_id)
        age = None if sensor.last_frame_mono is None else now_mono - sensor.last_frame_mono
        rows.append(
            {
                "id": sensor.sensor_id,
                "type": sensor.sensor_type,
                "agent_version": sensor.agent_version,
                "connected": sensor.connected,
                "fps": round(sensor.fps(now_mono), 2) if sensor.connected else 0.0,
                "last_frame_age_s": None if age is None else round(age, 4),
                "bodies": sensor.bodies_last if sensor.connected else 0,
                "frames_received": sensor.frames_received,
                "frames_rejected": dict(sensor.frames_rejected),
                "sequence_gaps": sensor.sequence_gaps,
                "clock_offset_s": sensor.clock_offset_s,
                "clock_source": sensor.clock_source,
                "clock_lag_s": sensor.lag_s,
                "round_trip_ms": None
                if sensor.round_trip.rtt_s is None
                else round(sensor.round_trip.rtt_s * 1000, 3),
                "calibration": {
                    "state": state,
                    "T_world_from_sensor": None if pose is None else pose.tolist(),
                },
                "drift": None
                if drift is None or (status := drift.status(sensor.sensor_id)) is None
                else status.to_json(),
            }
        )
        if sensor.moving:  # only then, so fixed sensors' rows are as before
            rows[-1]["pose_space"] = sensor.pose_space
    return rows
