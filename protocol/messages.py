"""The messages of protocol v1 as Python values (what ``protocol.wire`` encodes and decodes).

Field meanings, units and shapes are those of docs/protocol.md §6; ``protocol.wire`` is the only
place that turns them into bytes or back, and re-exports them (import them from there).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.hands import Hands
from skelfuse.protocol.skeleton import SKELETON_NAME


@dataclass(frozen=True, slots=True)
class Body:
    """One body in one sensor frame.

    tracking_id: the SDK's id for this body (uint64); stable while the sensor keeps tracking it.
    joints_m: (25, 3) float32, metres, the sensor's own camera frame (+X sensor-left, +Y up,
        +Z forward). Positions of NOT_TRACKED joints carry no meaning (may be NaN).
    states: (25,) uint8 :class:`~protocol.skeleton.TrackingState` per joint.
    hands: the sensor's hand states (Kinect v2 only, :mod:`protocol.hands`); None when the
        sensor does not report them (Azure Kinect, Femto, older agents).
    """

    tracking_id: int
    joints_m: npt.NDArray[np.float32]
    states: npt.NDArray[np.uint8]
    hands: Hands | None = None


_new_object = object.__new__
# The slots' own setters: a frozen dataclass's __init__ goes through object.__setattr__ once
# per field, which costs as much as the rest of a body's decode.
_set_tracking_id = cast(Any, Body).tracking_id.__set__
_set_joints = cast(Any, Body).joints_m.__set__
_set_states = cast(Any, Body).states.__set__
_set_hands = cast(Any, Body).hands.__set__


def checked_body(
    tracking_id: int,
    joints_m: npt.NDArray[np.float32],
    states: npt.NDArray[np.uint8],
    hands: Hands | None,
) -> Body:
    """``Body(tracking_id, joints_m, states, hands)`` for values the decoder has checked, in
    half the time (the same object: frozen, every field set; there are no post-init checks)."""
    body: Body = _new_object(Body)
    _set_tracking_id(body, tracking_id)
    _set_joints(body, joints_m)
    _set_states(body, states)
    _set_hands(body, hands)
    return body


@dataclass(frozen=True, slots=True)
class SensorPose:
    """A moving sensor's pose in its tracking space at a frame's capture instant
    (``T_space_from_sensor``, docs/protocol.md §6.3).

    position_m: (x, y, z), metres, the sensor's origin in the tracking space.
    rotation_xyzw: unit quaternion (x, y, z, w) rotating sensor axes into the space's axes.
    """

    position_m: tuple[float, float, float]
    rotation_xyzw: tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class Hello:
    """Agent registration; the first message of every connection (and after a server restart).

    pose_hint: optional ``T_world_from_sensor`` (4×4 float64) the agent believes in, with its
        ``pose_hint_source``: ``sim_truth`` (the simulator's true pose) or ``manual``. The server
        uses it only for a sensor that has no stored calibration.
    moving: the sensor moves (e.g. head-mounted); its frames carry a :class:`SensorPose` in the
        tracking space ``pose_space`` (an id like a sensor id; required when ``moving``).
    """

    sensor_id: str
    sensor_type: str
    agent_version: str
    fps: float
    t_ns: int
    skeleton: str = SKELETON_NAME
    pose_hint: npt.NDArray[np.float64] | None = None
    pose_hint_source: str | None = None
    moving: bool = False
    pose_space: str | None = None


@dataclass(frozen=True, slots=True)
class Welcome:
    """Server's answer to :class:`Hello`.

    features: what this server handles beyond v1's base (e.g. ``moving_sensors``); empty from
        servers that announce none, and from servers older than the field.
    """

    server_version: str
    heartbeat_interval_s: float
    t_ns: int
    features: tuple[str, ...] = ()


StackedBodies = tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]
"""A frame's bodies' joints (B, 25, 3) float32 metres and states (B, 25) uint8, stacked."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One captured sensor frame.

    seq: per-connection frame counter, +1 per captured frame (gaps mean frames were dropped).
    t_capture_ns: capture instant on the agent's clock, nanoseconds since the Unix epoch.
    floor: the SDK's floor plane (a, b, c, d) in the sensor frame, ``a·x + b·y + c·z + d = 0``
        with (a, b, c) a unit normal pointing up, or None.
    pose: the sensor's pose in its tracking space at ``t_capture_ns`` (moving sensors only),
        or None.
    stacked: set by the decoder only (not an argument: a frame built or replaced otherwise has
        None): the bodies' joints (B, 25, 3) float32 and states (B, 25) uint8 as the two
        arrays whose rows *are* the bodies' ``joints_m`` and ``states``, in body order, so
        fusion stacks them without copying (:meth:`skelfuse.fusion.sensors.TimedFrame.arrays`).
    """

    seq: int
    t_capture_ns: int
    bodies: tuple[Body, ...]
    floor: tuple[float, float, float, float] | None = None
    pose: SensorPose | None = None
    stacked: StackedBodies | None = field(default=None, init=False, repr=False, compare=False)


_set_seq = cast(Any, Frame).seq.__set__
_set_t_capture_ns = cast(Any, Frame).t_capture_ns.__set__
_set_bodies = cast(Any, Frame).bodies.__set__
_set_floor = cast(Any, Frame).floor.__set__
_set_pose = cast(Any, Frame).pose.__set__
_set_stacked = cast(Any, Frame).stacked.__set__


def checked_frame(
    seq: int,
    t_capture_ns: int,
    bodies: tuple[Body, ...],
    floor: tuple[float, float, float, float] | None,
    pose: SensorPose | None = None,
    stacked: StackedBodies | None = None,
) -> Frame:
    """``Frame(seq, t_capture_ns, bodies, floor, pose)`` for checked values, as
    :func:`checked_body`; ``stacked``: the arrays ``bodies``' rows are views of, in order
    (the decoder's), or None."""
    frame: Frame = _new_object(Frame)
    _set_seq(frame, seq)
    _set_t_capture_ns(frame, t_capture_ns)
    _set_bodies(frame, bodies)
    _set_floor(frame, floor)
    _set_pose(frame, pose)
    _set_stacked(frame, stacked)
    return frame


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """Liveness in either direction; ``t_ns`` is the sender's clock (Unix ns).

    ``echo_ns``: an agent answering a server heartbeat echoes the server's ``t_ns`` here, at
    once, so the server can measure the round trip and the agent's clock offset (NTP-style).
    """

    t_ns: int
    echo_ns: int | None = None


@dataclass(frozen=True, slots=True)
class Request:
    """Server -> agent request (e.g. a depth capture for calibration)."""

    request_id: int
    method: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Response:
    """Agent -> server answer to a :class:`Request`: ``result`` when ``ok``, else ``error``."""

    request_id: int
    ok: bool
    result: Any = None
    error: str | None = None


@dataclass(frozen=True, slots=True)
class ErrorMessage:
    """Server -> agent: why a message was refused. ``code`` ``not_registered`` asks for Hello."""

    code: str
    message: str


@dataclass(frozen=True, slots=True)
class Bye:
    """Agent -> server: a clean shutdown, so the sensor shows offline at once."""


Message = Hello | Welcome | Frame | Heartbeat | Request | Response | ErrorMessage | Bye
