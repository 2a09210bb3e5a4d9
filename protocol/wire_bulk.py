"""A frame's checks in bulk: the fast path of ``decode`` for a valid ``frame`` message.

:func:`frame_in_bulk` checks a whole frame at once: the scalar fields with exact ``type`` tests,
and the joints and states of all bodies joined into one blob each. The joints are judged on
their bytes first (the top byte of a float32 says whether |value| < 32 m), so a frame of
tracked joints needs no numpy call to check them, and one with NaN at its NOT_TRACKED joints
needs an ``isinf`` and the NaN write. It only ever says "valid, here are the values" or "not
sure" (``None``); it never names an error. On ``None``, ``protocol.wire`` runs the
precise checks in their documented order (docs/protocol.md §6.3), which accept the frame or
raise the one :class:`~protocol.errors.DecodeError` that names the first rule it breaks. So the
rejection reasons and messages are those of the precise path by construction; what this module
must get right is to accept exactly what the precise path accepts, with the same values
(tests/unit/test_wire_bulk.py checks both on generated valid and broken frames).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence
from operator import itemgetter
from typing import Any, Final, NamedTuple

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.constants import MAX_BODIES, MAX_COORDINATE_M
from skelfuse.protocol.hands import Hands, hands_quickly
from skelfuse.protocol.messages import SensorPose, StackedBodies
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.wire_checks import INT64_MAX, UINT64_MAX

_JOINT_BYTES: Final = JOINT_COUNT * 3 * 4
_LITTLE_ENDIAN: Final = sys.byteorder == "little"
_NUMBER: Final = (float, int)  # msgpack's numbers; type() is never bool here
_STATE_VALUES: Final = bytes(range(3))  # NOT_TRACKED, INFERRED, TRACKED
_UNSEEN: Final = bytes([1]) + bytes(255)  # a translate table: 1 where NOT_TRACKED, else 0
# A translate table for a float32's top byte (sign and 7 exponent bits): 1 where |value| >= 32
# or the value is NaN or infinite (exponent >= 132, top byte without its sign >= 0x42), else 0.
# float32(np.nan)'s bits: what NOT_TRACKED joints are set to; a numpy scalar, since comparing
# an array with a Python int first converts the int (twice the cost here).
_QUIET_NAN: Final = np.uint32(0x7FC00000)
_LARGE: Final = bytes(1 if (b & 0x7F) >= 0x42 else 0 for b in range(256))
# The rows of a (B, ...) array as a tuple of B views, by bodies count: itemgetter makes them in
# half the time of iterating the array (list(array)).
_ROWS: Final[tuple[Callable[[Any], tuple[Any, ...]], ...]] = (
    lambda _: (),
    lambda array: (array[0],),
    *(itemgetter(*range(count)) for count in range(2, MAX_BODIES + 1)),
)


class BulkFrame(NamedTuple):
    """A frame's checked values, ready for ``Frame`` and ``Body`` (B bodies).

    tracking_ids: B ids in 0..2^64-1, all different.
    joints_m: B arrays (25, 3) float32, metres, NOT_TRACKED joints NaN, every other joint finite
        and within ``MAX_COORDINATE_M``; each is a writable row of one (B, 25, 3) array.
    states: B arrays (25,) uint8 in 0..2; rows of one writable (B, 25) array.
    (Sequences: lists from the msgpack paths, tuples from :func:`frame_of_blobs`.)
    hands: B hand states (None where the body has none).
    pose: the sensor's checked pose (moving sensors), or None.
    stacked: the (B, 25, 3) and (B, 25) arrays ``joints_m`` and ``states`` are the rows of, or
        None (no bodies, or paths that build bodies one by one).
    """

    seq: int
    t_capture_ns: int
    tracking_ids: list[int]
    joints_m: Sequence[npt.NDArray[np.float32]]
    states: Sequence[npt.NDArray[np.uint8]]
    floor: tuple[float, float, float, float] | None
    hands: list[Hands | None]
    pose: SensorPose | None = None
    stacked: StackedBodies | None = None


def frame_in_bulk(raw: dict[str, Any]) -> BulkFrame | None:
    """The checked values of a ``frame`` message's map, or None if any check might fail.

    ``raw`` is the map msgpack decoded (str keys). None means only "take the precise path":
    this function raises nothing for bad input.
    """
    if not _LITTLE_ENDIAN:  # the arrays below are read in native order
        return None
    seq = raw.get("seq")
    t_capture_ns = raw.get("t_capture_ns")
    bodies = raw.get("bodies")
    # ``type(x) is int`` also refuses bool, as the precise checks do.
    if (
        type(seq) is not int
        or type(t_capture_ns) is not int
        or not 0 <= seq <= INT64_MAX
        or not 0 <= t_capture_ns <= INT64_MAX
        or type(bodies) is not list
        or len(bodies) > MAX_BODIES
        or raw.get("pose") is not None  # a moving sensor's frame: the precise path checks it
    ):
        return None
    floor = checked_floor(raw.get("floor"))
    if isinstance(floor, bool):  # False: the floor needs the precise checks
        return None
    ids: list[int] = []
    joint_blobs: list[bytes] = []
    state_blobs: list[bytes] = []
    hands: list[Hands | None] = []
    try:
        for body in bodies:
            # Subscripts, not .get (a missing key ends in the except below): the loop runs
            # once per body, and method calls are most of its cost.
            if type(body) is not dict:
                return None
            tracking_id = body["id"]
            joints = body["joints"]
            states = body["states"]
            if (
                type(tracking_id) is not int
                or not 0 <= tracking_id <= UINT64_MAX
                or type(joints) is not bytes
                or len(joints) != _JOINT_BYTES
                or type(states) is not bytes
                or len(states) != JOINT_COUNT
            ):
                return None
            hand_states = None
            if "hands" in body and body["hands"] is not None:
                hand_states = hands_quickly(body["hands"])
                if hand_states is None:
                    return None
            ids.append(tracking_id)
            joint_blobs.append(joints)
            state_blobs.append(states)
            hands.append(hand_states)
    except KeyError:
        return None
    return frame_of_blobs(seq, t_capture_ns, ids, joint_blobs, state_blobs, hands, floor)


def frame_of_blobs(
    seq: int,
    t_capture_ns: int,
    ids: list[int],
    joint_blobs: list[bytes],
    state_blobs: list[bytes],
    hands: list[Hands | None],
    floor: tuple[float, float, float, float] | None,
    pose: SensorPose | None = None,
) -> BulkFrame | None:
    """The frame's checked values from its fields, each checked already for type, range and
    size but for the bodies' ids (all different), states (0..2) and joints; None as above.

    joint_blobs: B blobs of 300 bytes; state_blobs: B blobs of 25 bytes; ids: B ints in
    0..2^64-1; hands: B checked hand states or None; pose: checked, or None.
    """
    if len(set(ids)) != len(ids):
        return None
    if not ids:
        return BulkFrame(seq, t_capture_ns, ids, [], [], floor, hands, pose)
    all_states = b"".join(state_blobs)
    if all_states.translate(None, _STATE_VALUES):  # a byte other than 0, 1, 2 is left
        return None
    all_joints = b"".join(joint_blobs)
    count = len(ids)
    # np.ndarray on a writable copy: a third cheaper than frombuffer + reshape, same array.
    joints = np.ndarray((count, JOINT_COUNT, 3), np.float32, bytearray(all_joints))
    if not _joints_valid(all_joints, all_states, joints):
        return None
    states = np.ndarray((count, JOINT_COUNT), np.uint8, bytearray(all_states))
    rows = _ROWS[count]
    return BulkFrame(
        seq, t_capture_ns, ids, rows(joints), rows(states), floor, hands, pose, (joints, states)
    )


def _joints_valid(all_joints: bytes, all_states: bytes, joints: npt.NDArray[np.float32]) -> bool:
    """The joint rules of all bodies at once; sets NOT_TRACKED joints of ``joints`` to NaN.

    Most frames are settled on the bytes alone, without a numpy reduction: the top byte of each
    little-endian float32 tells whether the value is small (|v| < 32 m, hence finite and within
    range) or not. Large values (NaN, ±inf, 32 m and beyond) are fine only at NOT_TRACKED joints
    and only if none is infinite; anything less clear-cut is decided on the floats.

    Args:
        all_joints: B × 300 bytes, the bodies' joints blobs joined; all_states: B × 25 bytes,
            each 0, 1 or 2; joints: (B, 25, 3) float32, a writable C-ordered copy of
            ``all_joints``.
    """
    large = all_joints[3::4].translate(_LARGE)  # one byte per coordinate: 1 if large
    if b"\x00" not in all_states:  # every joint seen: every value must be small, or checked
        return b"\x01" not in large or _valid_on_the_floats(joints, all_states)
    unseen = all_states.translate(_UNSEEN)  # one byte per joint: 1 if NOT_TRACKED
    if b"\x01" not in large:
        mask = np.frombuffer(unseen, dtype=np.bool_).repeat(3)
    elif large[0::3] == unseen and large[1::3] == unseen and large[2::3] == unseen:
        # The usual case: every coordinate of every NOT_TRACKED joint is large (the NaN agents
        # SHOULD send) and no other is. If they are all the very NaN written below (numpy's, as
        # our agents send), there is nothing to check or write: the large ones are that many.
        if np.count_nonzero(joints.view(np.uint32) == _QUIET_NAN) == 3 * unseen.count(1):
            return True
        # count_nonzero: a third of the cost of a logical_or reduction on a few hundred flags.
        if np.count_nonzero(np.isinf(joints)):  # NOT_TRACKED joints may be NaN, never ±inf
            return False
        # Then the large flags are the mask to write NaN through.
        mask = np.frombuffer(large, dtype=np.bool_)
    elif _large_where_seen(large, unseen):  # a tracked joint is 32 m or more away, or not finite
        return _valid_on_the_floats(joints, all_states)
    else:
        if np.count_nonzero(np.isinf(joints)):
            return False
        mask = np.frombuffer(unseen, dtype=np.bool_).repeat(3)
    # NOT_TRACKED positions carry no meaning: NaN, as the precise checks write (through a flat
    # view: the masks are flat).
    np.putmask(joints.reshape(-1), mask, np.nan)
    return True


def _large_where_seen(large: bytes, unseen: bytes) -> bool:
    """Whether a joint that is not NOT_TRACKED has a large coordinate.

    large: one byte (0 or 1) per coordinate; unseen: one byte (0 or 1) per joint.
    """
    # OR of each joint's x, y and z flags, eight bits per joint, as one integer.
    large_joints = (
        int.from_bytes(large[0::3], "little")
        | int.from_bytes(large[1::3], "little")
        | int.from_bytes(large[2::3], "little")
    )
    return bool(large_joints & ~int.from_bytes(unseen, "little"))


def _valid_on_the_floats(joints: npt.NDArray[np.float32], all_states: bytes) -> bool:
    """:func:`_joints_valid` decided on the floats (large values at tracked joints, or ±inf)."""
    flat = joints.reshape(-1)  # a view: what is written here is written to ``joints``
    if b"\x00" in all_states:  # some joints are NOT_TRACKED: their values count only if ±inf
        if np.count_nonzero(np.isinf(flat)):
            return False
        unseen = np.frombuffer(all_states.translate(_UNSEEN), dtype=np.bool_).repeat(3)
        np.putmask(flat, unseen, 0.0)
        within = _within_range(flat)
        np.putmask(flat, unseen, np.nan)
        return within
    return _within_range(flat)


def _within_range(joints: npt.NDArray[np.float32]) -> bool:
    """Every value finite and within ±``MAX_COORDINATE_M`` (a NaN makes the maximum NaN);
    ``joints`` is flat."""
    return float(np.maximum.reduce(np.abs(joints))) <= MAX_COORDINATE_M


def checked_floor(value: object) -> tuple[float, float, float, float] | bool | None:
    """A checked floor plane (a list, or a tuple from a typed decoder), None for none, False for
    "take the precise path"."""
    if value is None:
        return None
    if (type(value) is not list and type(value) is not tuple) or len(value) != 4:
        return False
    a, b, c, d = value
    if not (
        type(a) in _NUMBER and type(b) in _NUMBER and type(c) in _NUMBER and type(d) in _NUMBER
    ):
        return False
    a, b, c, d = float(a), float(b), float(c), float(d)
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c) and math.isfinite(d)):
        return False
    # sum() of the same three squares, as the precise check does: the same verdict to the bit.
    if abs(math.sqrt(sum((a * a, b * b, c * c))) - 1.0) > 1e-3:
        return False
    return (a, b, c, d)
