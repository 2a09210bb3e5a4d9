"""Agent <-> server messages, version 1: msgpack maps in single ZeroMQ frames.

``encode(message) -> bytes`` and ``decode(buf) -> message`` are the only way messages cross the
wire, on both sides. ``decode`` is the trust boundary: everything it returns has been checked
(version, types, shapes, finite values, ranges, sizes), and everything it refuses raises
:class:`~protocol.errors.DecodeError` with a short ``reason`` used for counting. The checks of
single values are in :mod:`protocol.wire_checks`, a frame's fast bulk path in ``wire_bulk`` and
its fastest, for frames in the reference encoder's exact bytes, in ``wire_canonical``.

The byte-level format is specified in ``docs/protocol.md``; keep the two in step.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any, Final

import msgpack
import numpy as np

from skelfuse.protocol.constants import MAX_BODIES, MAX_MESSAGE_BYTES, PROTOCOL_VERSION
from skelfuse.protocol.errors import DecodeError, VersionMismatch
from skelfuse.protocol.hands import check_hands
from skelfuse.protocol.messages import (
    Body,
    Bye,
    ErrorMessage,
    Frame,
    Heartbeat,
    Hello,
    Message,
    Request,
    Response,
    SensorPose,
    Welcome,
    checked_body,
    checked_frame,
)
from skelfuse.protocol.skeleton import JOINT_COUNT, SKELETON_NAME
from skelfuse.protocol.wire_bulk import BulkFrame, frame_in_bulk
from skelfuse.protocol.wire_canonical import canonical_frame
from skelfuse.protocol.wire_checks import (
    UINT64_MAX,
    field_of,
    finite_float,
    joint_arrays,
    rigid_pose,
    sensor_pose,
    uint,
)

SENSOR_ID_PATTERN: Final = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
# "rgb": one ordinary camera through a 2-D/3-D keypoint model (agent/sources/mono.py).
SENSOR_TYPES: Final = frozenset({"kinect_v2", "azure_kinect", "femto", "rgb", "sim", "replay"})
POSE_HINT_SOURCES: Final = frozenset({"sim_truth", "manual"})

__all__ = [
    "POSE_HINT_SOURCES",
    "SENSOR_ID_PATTERN",
    "SENSOR_TYPES",
    "Body",
    "Bye",
    "ErrorMessage",
    "Frame",
    "Heartbeat",
    "Hello",
    "Message",
    "Request",
    "Response",
    "SensorPose",
    "Welcome",
    "decode",
    "decode_frame_precisely",
    "encode",
]

# --- encoding ---------------------------------------------------------------------------------


def encode(message: Message) -> bytes:
    """Serialise a message to its wire bytes (deterministic: same message, same bytes)."""
    body: dict[str, Any]
    match message:
        case Frame():
            body = {
                "type": "frame",
                "seq": int(message.seq),
                "t_capture_ns": int(message.t_capture_ns),
                "bodies": [_encode_body(b) for b in message.bodies],
                "floor": [float(x) for x in message.floor] if message.floor is not None else None,
            }
            if message.pose is not None:  # moving sensors only; v1 frames without it unchanged
                body["pose"] = [
                    float(x) for x in message.pose.position_m + message.pose.rotation_xyzw
                ]
        case Heartbeat():
            body = {"type": "heartbeat", "t_ns": int(message.t_ns)}
            if message.echo_ns is not None:
                body["echo_ns"] = int(message.echo_ns)
        case Hello():
            body = {
                "type": "hello",
                "sensor_id": message.sensor_id,
                "sensor_type": message.sensor_type,
                "skeleton": message.skeleton,
                "agent_version": message.agent_version,
                "fps": float(message.fps),
                "t_ns": message.t_ns,
            }
            if message.pose_hint is not None:
                body["pose_hint"] = {
                    "T_world_from_sensor": [float(x) for x in message.pose_hint.reshape(16)],
                    "source": message.pose_hint_source or "manual",
                }
            if message.moving:
                body["moving"] = True
            if message.pose_space is not None:
                body["pose_space"] = message.pose_space
        case Welcome():
            body = {
                "type": "welcome",
                "server_version": message.server_version,
                "heartbeat_interval_s": float(message.heartbeat_interval_s),
                "t_ns": message.t_ns,
            }
            if message.features:
                body["features"] = list(message.features)
        case Request():
            body = {
                "type": "request",
                "id": message.request_id,
                "method": message.method,
                "params": message.params,
            }
        case Response():
            body = {"type": "response", "id": message.request_id, "ok": message.ok}
            if message.ok:
                body["result"] = message.result
            else:
                body["error"] = message.error or "unspecified error"
        case ErrorMessage():
            body = {"type": "error", "code": message.code, "message": message.message}
        case Bye():
            body = {"type": "bye"}
    packed: bytes = msgpack.packb({"v": PROTOCOL_VERSION, **body}, use_bin_type=True)
    return packed


def _encode_body(body: Body) -> dict[str, Any]:
    joints = np.ascontiguousarray(body.joints_m, dtype="<f4")
    states = np.ascontiguousarray(body.states, dtype=np.uint8)
    if joints.shape != (JOINT_COUNT, 3) or states.shape != (JOINT_COUNT,):
        raise ValueError(
            f"a body needs (25, 3) joints and (25,) states, got {joints.shape} and {states.shape}"
        )
    encoded: dict[str, Any] = {
        "id": int(body.tracking_id),
        "joints": joints.tobytes(),
        "states": states.tobytes(),
    }
    if body.hands is not None:  # only Kinect v2 reports them (docs/protocol.md §7.4)
        encoded["hands"] = body.hands.to_wire()
    return encoded


# --- decoding (the trust boundary) ------------------------------------------------------------


def decode(buf: bytes, max_bytes: int = MAX_MESSAGE_BYTES) -> Message:
    """Parse and validate one message.

    ``max_bytes`` may be raised (up to ``MAX_RESPONSE_BYTES``) by a server that is waiting
    for an agent's answer to a request; the larger limit applies to ``response`` messages only.

    Raises:
        DecodeError: with ``reason`` ``too_large``, ``malformed``, ``version``, ``unknown_type``,
            ``bad_field``, ``bad_shape``, ``non_finite`` or ``out_of_range``.
    """
    if len(buf) > max_bytes:
        raise DecodeError("too_large", f"message of {len(buf)} bytes > {max_bytes}")
    canonical = canonical_frame(buf)  # nearly every message: a frame from one of our agents
    if canonical is not None:
        return _frame_of(canonical)
    try:
        raw = msgpack.unpackb(
            buf,
            raw=False,
            strict_map_key=True,
            max_array_len=64,
            max_map_len=32,
            max_str_len=4096,
            max_bin_len=max(4096, max_bytes if max_bytes > MAX_MESSAGE_BYTES else 0),
            max_ext_len=0,
        )
    except (ValueError, msgpack.UnpackException) as exc:  # limits, garbage, trailing bytes
        raise DecodeError("malformed", f"not a msgpack message: {exc}") from exc
    if not isinstance(raw, dict):
        raise DecodeError("malformed", f"message must be a map, got {type(raw).__name__}")
    version = raw.get("v")
    # Not isinstance: True and 1.0 both compare equal to 1.
    if type(version) is not int or version != PROTOCOL_VERSION:
        raise VersionMismatch(version, PROTOCOL_VERSION)
    kind = raw.get("type")
    decoder = _DECODERS.get(kind) if isinstance(kind, str) else None
    if decoder is None:
        raise DecodeError("unknown_type", f"unknown message type {kind!r}")
    if kind != "response" and len(buf) > MAX_MESSAGE_BYTES:
        raise DecodeError("too_large", f"{kind} message of {len(buf)} bytes > {MAX_MESSAGE_BYTES}")
    return decoder(raw)


def _decode_frame(raw: dict[str, Any]) -> Frame:
    bulk = frame_in_bulk(raw)
    if bulk is None:
        return decode_frame_precisely(raw)
    return _frame_of(bulk)


def _frame_of(bulk: BulkFrame) -> Frame:
    seq, t_capture_ns, tracking_ids, joints_m, states, floor, hands, pose, stacked = bulk
    bodies = tuple(map(checked_body, tracking_ids, joints_m, states, hands))
    return checked_frame(seq, t_capture_ns, bodies, floor, pose, stacked)


def decode_frame_precisely(raw: dict[str, Any]) -> Frame:
    """A ``frame`` map checked field by field in the order of docs/protocol.md §6.3.

    Raises:
        DecodeError: the first rule broken (``bad_field``, ``bad_shape``, ``non_finite``...).
    """
    seq = uint(raw, "seq")
    t_capture_ns = uint(raw, "t_capture_ns")
    bodies_raw = field_of(raw, "bodies", list)
    if len(bodies_raw) > MAX_BODIES:
        raise DecodeError("bad_shape", f"{len(bodies_raw)} bodies > {MAX_BODIES}")
    bodies = tuple(_decode_body(b, i) for i, b in enumerate(bodies_raw))
    if len({b.tracking_id for b in bodies}) != len(bodies):
        raise DecodeError("bad_field", "two bodies share one tracking id")
    floor_raw = raw.get("floor")
    floor: tuple[float, float, float, float] | None = None
    if floor_raw is not None:
        if not isinstance(floor_raw, list) or len(floor_raw) != 4:
            raise DecodeError("bad_shape", "floor must be [a, b, c, d] or nil")
        values = tuple(finite_float({"floor": x}, "floor") for x in floor_raw)
        normal = math.sqrt(sum(v * v for v in values[:3]))
        if abs(normal - 1.0) > 1e-3:
            raise DecodeError("out_of_range", f"floor normal must be a unit vector, |n| = {normal}")
        floor = (values[0], values[1], values[2], values[3])
    pose_raw = raw.get("pose")
    pose = sensor_pose(pose_raw) if pose_raw is not None else None
    return Frame(seq=seq, t_capture_ns=t_capture_ns, bodies=bodies, floor=floor, pose=pose)


def _decode_body(raw: object, index: int) -> Body:
    if not isinstance(raw, dict):
        raise DecodeError("bad_field", f"body {index} must be a map")
    tracking_id = uint(raw, "id", UINT64_MAX)
    joints_buf = field_of(raw, "joints", bytes)
    states_buf = field_of(raw, "states", bytes)
    joints, states = joint_arrays(joints_buf, states_buf, index)
    hands = check_hands(raw.get("hands"), index)
    return Body(tracking_id=tracking_id, joints_m=joints, states=states, hands=hands)


def _decode_hello(raw: dict[str, Any]) -> Hello:
    sensor_id = field_of(raw, "sensor_id", str)
    if not SENSOR_ID_PATTERN.fullmatch(sensor_id):  # match() + "$" accepts a final "\n"
        raise DecodeError(
            "bad_field",
            f"sensor_id {sensor_id[:80]!r} must be 1-64 characters of A-Z a-z 0-9 . _ - "
            "starting with a letter or digit",
        )
    sensor_type = field_of(raw, "sensor_type", str)
    if sensor_type not in SENSOR_TYPES:
        raise DecodeError(
            "bad_field", f"sensor_type {sensor_type[:40]!r} not one of {sorted(SENSOR_TYPES)}"
        )
    skeleton = field_of(raw, "skeleton", str)
    if skeleton != SKELETON_NAME:
        raise DecodeError(
            "bad_field", f"skeleton {skeleton[:40]!r} not supported (agents send {SKELETON_NAME})"
        )
    fps = finite_float(raw, "fps")
    if not 0 < fps <= 240:
        raise DecodeError("out_of_range", f"fps {fps} out of range (0, 240]")
    pose_hint = None
    pose_source = None
    hint = raw.get("pose_hint")
    if hint is not None:
        if not isinstance(hint, dict):
            raise DecodeError("bad_field", "pose_hint must be a map")
        matrix = field_of(hint, "T_world_from_sensor", list)
        pose_source = field_of(hint, "source", str)
        if pose_source not in POSE_HINT_SOURCES:
            raise DecodeError("bad_field", f"pose_hint source must be one of {POSE_HINT_SOURCES}")
        pose_hint = rigid_pose(matrix)
    moving = raw.get("moving", False)
    if type(moving) is not bool:
        raise DecodeError("bad_field", "moving must be true or false")
    pose_space = raw.get("pose_space")
    if pose_space is not None and (
        type(pose_space) is not str or not SENSOR_ID_PATTERN.fullmatch(pose_space)
    ):
        raise DecodeError("bad_field", "pose_space must be an id like a sensor_id")
    if moving and pose_space is None:
        raise DecodeError("bad_field", "a moving sensor must name its pose_space")
    return Hello(
        sensor_id=sensor_id,
        sensor_type=sensor_type,
        agent_version=field_of(raw, "agent_version", str)[:64],
        fps=fps,
        t_ns=uint(raw, "t_ns"),
        skeleton=skeleton,
        pose_hint=pose_hint,
        pose_hint_source=pose_source,
        moving=moving,
        pose_space=pose_space,
    )


def _decode_welcome(raw: dict[str, Any]) -> Welcome:
    features = raw.get("features", [])
    # Names this agent does not know are kept: they say only what the server can do.
    if type(features) is not list or not all(type(f) is str and len(f) <= 64 for f in features):
        raise DecodeError("bad_field", "features must be a list of names")
    return Welcome(
        server_version=field_of(raw, "server_version", str),
        heartbeat_interval_s=finite_float(raw, "heartbeat_interval_s"),
        t_ns=uint(raw, "t_ns"),
        features=tuple(features),
    )


def _decode_heartbeat(raw: dict[str, Any]) -> Heartbeat:
    echo = uint(raw, "echo_ns") if raw.get("echo_ns") is not None else None
    return Heartbeat(t_ns=uint(raw, "t_ns"), echo_ns=echo)


def _decode_request(raw: dict[str, Any]) -> Request:
    return Request(
        request_id=uint(raw, "id"),
        method=field_of(raw, "method", str),
        params=field_of(raw, "params", dict),
    )


def _decode_response(raw: dict[str, Any]) -> Response:
    ok = field_of(raw, "ok", bool)
    if ok:
        return Response(request_id=uint(raw, "id"), ok=True, result=raw.get("result"))
    return Response(request_id=uint(raw, "id"), ok=False, error=field_of(raw, "error", str))


def _decode_error(raw: dict[str, Any]) -> ErrorMessage:
    return ErrorMessage(code=field_of(raw, "code", str), message=field_of(raw, "message", str))


def _decode_bye(raw: dict[str, Any]) -> Bye:
    return Bye()


_DECODERS: Final[dict[str, Callable[[dict[str, Any]], Message]]] = {
    "frame": _decode_frame,
    "heartbeat": _decode_heartbeat,
    "hello": _decode_hello,
    "welcome": _decode_welcome,
    "request": _decode_request,
    "response": _decode_response,
    "error": _decode_error,
    "bye": _decode_bye,
}
