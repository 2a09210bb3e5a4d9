"""Hand states on the wire (docs/protocol.md §7.4): golden bytes, both paths, every rejection.

The golden file ``tests/data/frame_hands_v1.bin`` is the golden frame of test_wire.py with
hand states; regenerate it (only after a deliberate format change) with
``SKELFUSE_REGEN_GOLDEN=1 python -m pytest tests/unit/test_wire_hands.py``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import msgpack
import pytest

from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.hands import (
    UNKNOWN_HANDS,
    HandConfidence,
    Hands,
    HandState,
    check_hands,
    hands_from_sdk,
    hands_quickly,
)
from skelfuse.protocol.wire import Frame, decode, decode_frame_precisely, encode
from skelfuse.protocol.wire_bulk import frame_in_bulk
from tests.unit.test_wire import assert_same, golden_bytes, golden_frame, pack, raw_body, raw_frame

CLOSED_LEFT_OPEN_RIGHT = Hands(
    HandState.CLOSED, HandState.OPEN, HandConfidence.HIGH, HandConfidence.LOW
)


def hands_frame() -> Frame:
    frame = golden_frame()
    body = dataclasses.replace(frame.bodies[0], hands=CLOSED_LEFT_OPEN_RIGHT)
    return dataclasses.replace(frame, bodies=(body,))


def test_golden_frame_with_hands() -> None:
    fixed = hands_frame()
    golden = golden_bytes("frame_hands_v1.bin", encode(fixed))
    assert encode(fixed) == golden
    assert_same(decode(golden), fixed, "frame_hands_v1")
    # The only difference from frame_v1.bin: the body map has a 4th key, "hands" [3, 2, 1, 0].
    plain = golden_bytes("frame_v1.bin", encode(golden_frame()))
    extra = b"\xa5hands\x94\x03\x02\x01\x00"
    assert len(golden) == len(plain) + len(extra)
    assert extra in golden and extra not in plain


def test_a_body_without_hands_encodes_as_before() -> None:
    # Old agents' bytes are unchanged: the key is written only when a body has hand states.
    assert b"hands" not in encode(golden_frame())
    assert decode(encode(golden_frame())).bodies[0].hands is None  # type: ignore[union-attr]


def test_an_old_server_ignores_hands() -> None:
    # What a server that does not know the key sees: a body map with one unknown key.
    raw = msgpack.unpackb(encode(hands_frame()), raw=False)
    assert raw["bodies"][0]["hands"] == [3, 2, 1, 0]
    del raw["bodies"][0]["hands"]
    assert_same(decode(pack(raw)), golden_frame(), "without hands")


def test_nil_hands_is_no_hands() -> None:
    decoded = decode(pack(raw_frame(bodies=[raw_body(hands=None)])))
    assert isinstance(decoded, Frame)
    assert decoded.bodies[0].hands is None


@pytest.mark.parametrize(
    ("hands", "reason"),
    [
        ([3, 2, 1], "bad_shape"),
        ([3, 2, 1, 0, 0], "bad_shape"),
        ({"left": 3}, "bad_shape"),
        ("3210", "bad_shape"),
        (b"\x03\x02\x01\x00", "bad_shape"),
        ([3, 2, True, 0], "bad_field"),
        ([3.0, 2, 1, 0], "bad_field"),
        ([3, None, 1, 0], "bad_field"),
        ([5, 2, 1, 0], "out_of_range"),
        ([3, -1, 1, 0], "out_of_range"),
        ([3, 2, 2, 0], "out_of_range"),
        ([3, 2, 1, 255], "out_of_range"),
    ],
)
def test_bad_hands(hands: Any, reason: str) -> None:
    buf = pack(raw_frame(bodies=[raw_body(hands=hands)]))
    with pytest.raises(DecodeError) as caught:
        decode(buf)
    assert caught.value.reason == reason
    assert "hand" in str(caught.value)
    # The bulk path declines, so the precise path names the rule.
    assert frame_in_bulk(msgpack.unpackb(buf, raw=False)) is None


def test_hands_are_checked_after_the_joints() -> None:
    # Documented order: a body's joint rules come before its hands (§6.3 step 3.11).
    body = raw_body(hands=[9, 9, 9, 9], states=bytes([7] * 25))
    with pytest.raises(DecodeError) as caught:
        decode(pack(raw_frame(bodies=[body])))
    assert "tracking state" in str(caught.value)


@pytest.mark.parametrize("values", [[0, 0, 0, 0], [4, 1, 0, 1], [2, 3, 1, 1]])
def test_bulk_and_precise_paths_agree(values: list[int]) -> None:
    raw = raw_frame(bodies=[raw_body(1, hands=values), raw_body(2)])
    bulk = frame_in_bulk(raw)
    assert bulk is not None
    precise = decode_frame_precisely(raw)
    assert bulk.hands == [b.hands for b in precise.bodies]
    assert precise.bodies[0].hands == tuple(values)
    assert precise.bodies[1].hands is None
    hands = precise.bodies[0].hands
    assert type(hands.left) is HandState and type(hands.right) is HandState


def test_quick_and_precise_checks_accept_the_same_values() -> None:
    for values in ([s, t, a, b] for s in range(-1, 6) for t in (0, 4, 5) for a in (-1, 0, 1, 2)
                   for b in (0, 1)):  # fmt: skip
        try:
            precise: Hands | None = check_hands(values, 0)
        except DecodeError:
            precise = None
        assert hands_quickly(values) == precise, values


def test_hands_from_sdk_maps_unknown_values_to_unknown() -> None:
    assert hands_from_sdk(3, 2, 1, 0) == CLOSED_LEFT_OPEN_RIGHT
    assert hands_from_sdk(7, -1, 5, 1) == Hands(
        HandState.UNKNOWN, HandState.UNKNOWN, HandConfidence.LOW, HandConfidence.HIGH
    )
    assert UNKNOWN_HANDS.to_wire() == [0, 0, 0, 0]
