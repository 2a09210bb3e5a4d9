"""The fastest path of ``decode``: a ``frame`` encoded byte for byte as the reference encoder
writes it, parsed by msgspec into typed fields instead of msgpack into dicts.

Every frame the project's agents send is in that canonical form (docs/protocol.md §3.3: keys
in §6's order, ``floor`` always written, integers in their shortest form, floats as float64,
``hands`` only when present). msgspec checks the fields' types, sizes and integer ranges while
it parses (in C), which leaves the per-body Python loop of :func:`~protocol.wire_bulk.frame_in_bulk`
with nothing to do; the joints and states are then checked by
:func:`~protocol.wire_bulk.frame_of_blobs`, as on the bulk path.

Why "canonical" only: msgspec accepts some messages that ``decode``'s msgpack limits refuse
(a map repeating a key more than 32 times, an array over 64 elements) and reads others
differently (a repeated key: the last wins). :func:`canonical_frame` therefore re-encodes what
it parsed and takes it only if that gives the very bytes received; anything else, valid or not
(other key orders, float32 floors, unknown keys, absent ``floor``, broken messages), returns
None and ``decode`` goes the usual way, so every rejection keeps its reason and message. Like
``wire_bulk``, this module only says "valid, here are the values" or "not sure".

msgspec is optional (the ``server`` extra): without it, :func:`canonical_frame` always says
"not sure". Agents never need it.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from skelfuse.protocol.constants import MAX_BODIES
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.hands import hands_quickly
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.wire_bulk import BulkFrame, frame_of_blobs
from skelfuse.protocol.wire_checks import INT64_MAX, sensor_pose

try:
    import msgspec
except ImportError:  # pragma: no cover - the fast path is off without it
    msgspec = None  # type: ignore[assignment]

ENABLED: bool = msgspec is not None
"""Whether :func:`canonical_frame` runs at all (tests switch it off to compare the paths)."""

if msgspec is not None:
    _UINT63 = msgspec.Meta(ge=0, le=INT64_MAX)
    _JOINT_BYTES = JOINT_COUNT * 3 * 4

    class _Body(msgspec.Struct, forbid_unknown_fields=True, omit_defaults=True):
        # ge=0 and msgpack's own limit (msgspec reads integers up to 2^64-1): the id's range.
        id: Annotated[int, msgspec.Meta(ge=0)]
        joints: Annotated[bytes, msgspec.Meta(min_length=_JOINT_BYTES, max_length=_JOINT_BYTES)]
        states: Annotated[bytes, msgspec.Meta(min_length=JOINT_COUNT, max_length=JOINT_COUNT)]
        hands: list[int] | None = None

    # omit_defaults: ``pose`` is written only when present; ``floor`` has no default (always).
    class _Frame(msgspec.Struct, forbid_unknown_fields=True, omit_defaults=True):
        v: Literal[1]
        type: Literal["frame"]
        seq: Annotated[int, _UINT63]
        t_capture_ns: Annotated[int, _UINT63]
        bodies: Annotated[list[_Body], msgspec.Meta(max_length=MAX_BODIES)]
        floor: tuple[float, float, float, float] | None
        pose: tuple[float, float, float, float, float, float, float] | None = None

    _decode_frame: Any = msgspec.msgpack.Decoder(_Frame).decode
    _encode: Any = msgspec.msgpack.Encoder().encode


def canonical_frame(buf: bytes) -> BulkFrame | None:
    """The checked values of a canonical ``frame`` message, or None ("not sure": take the
    msgpack path). Raises nothing for bad input.

    Args:
        buf: the message as received (its size already checked against the limit).
    """
    if not ENABLED:
        return None
    try:
        frame = _decode_frame(buf)
    except Exception:  # msgspec.DecodeError, UnicodeDecodeError for a bad str...: "not sure"
        return None
    if _encode(frame) != buf:  # not the canonical bytes of what was parsed
        return None
    floor = frame.floor
    if floor is not None:
        a, b, c, d = floor
        # A NaN or infinity makes the sum so (a finite sum that overflows is only "not sure");
        # the norm is summed as the precise check sums it, for the same verdict to the bit.
        if (
            not math.isfinite(a + b + c + d)
            or abs(math.sqrt(sum((a * a, b * b, c * c))) - 1.0) > 1e-3
        ):
            return None
    pose = None
    if frame.pose is not None:  # a moving sensor's frame: the very check of the precise path
        try:
            pose = sensor_pose(frame.pose)
        except DecodeError:
            return None
    bodies = frame.bodies
    hands: list[Any] = [body.hands for body in bodies]
    if hands.count(None) != len(hands):  # some bodies carry hand states: check and convert
        for index, wire_hands in enumerate(hands):
            if wire_hands is not None:
                hands[index] = hands_quickly(wire_hands)
                if hands[index] is None:
                    return None
    return frame_of_blobs(
        frame.seq,
        frame.t_capture_ns,
        [body.id for body in bodies],
        [body.joints for body in bodies],
        [body.states for body in bodies],
        hands,
        floor,
        pose,
    )
