"""The msgspec path of ``decode`` (``protocol.wire_canonical``) against the msgpack paths.

Frames in the reference encoder's exact bytes take it; it must give what the msgpack paths give,
bit for bit, and say "not sure" for everything else (other encodings, broken messages), so that
``decode``'s result and every rejection are as without it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import Any

import msgpack
import pytest
from hypothesis import assume, given

from skelfuse.protocol import wire, wire_canonical
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.wire import Frame, decode, decode_frame_precisely, encode
from skelfuse.protocol.wire_canonical import canonical_frame
from tests.unit.test_wire_bulk import assert_identical, frame_maps, raw_of
from tests.unit.test_wire_properties import frames

pytestmark = pytest.mark.skipif(not wire_canonical.ENABLED, reason="msgspec is not installed")


def without_canonical(buf: bytes) -> Frame | tuple[Any, ...] | object:
    """``decode(buf)``'s outcome with the msgspec path off."""
    saved = getattr(wire, "canonical_frame")  # noqa: B009 (wire does not re-export it)
    setattr(wire, "canonical_frame", lambda _: None)  # noqa: B010
    try:
        return decode(buf)
    except DecodeError as exc:
        return (type(exc), exc.reason, str(exc))
    finally:
        setattr(wire, "canonical_frame", saved)  # noqa: B010


def outcome(buf: bytes) -> Frame | tuple[Any, ...] | object:
    try:
        return decode(buf)
    except DecodeError as exc:
        return (type(exc), exc.reason, str(exc))


@given(frame=frames())
def test_frames_from_the_reference_encoder_take_it_with_the_same_values(frame: Frame) -> None:
    buf = encode(frame)
    assert canonical_frame(buf) is not None
    decoded = decode(buf)
    assert isinstance(decoded, Frame)
    assert_identical(decoded, decode_frame_precisely(raw_of(frame)))


@given(raw=frame_maps())
def test_any_frame_map_decodes_as_without_it(raw: dict[str, Any]) -> None:
    try:
        buf = msgpack.packb({"v": 1, **raw}, use_bin_type=True)
    except OverflowError:  # an int beyond msgpack's 64 bits: no bytes to decode
        assume(False)
    got, want = outcome(buf), without_canonical(buf)
    if isinstance(want, Frame):
        assert isinstance(got, Frame)
        assert_identical(got, want)
    else:
        assert got == want


def _variants(buf: bytes) -> Iterator[tuple[str, bytes]]:
    raw = msgpack.unpackb(buf, raw=False)
    yield "keys in another order", msgpack.packb(dict(reversed(list(raw.items()))))
    yield "no floor key", msgpack.packb({k: v for k, v in raw.items() if k != "floor"})
    yield "an unknown key", msgpack.packb({**raw, "extra": 1})
    yield (
        "an unknown body key",
        msgpack.packb({**raw, "bodies": [{**b, "hand_state": 2} for b in raw["bodies"]]}),
    )
    floor32 = msgpack.packb(raw, use_single_float=True)
    yield "float32 floor", floor32
    yield "a trailing byte", buf + b"\x00"
    # seq repeated 40 times: msgspec would read the last, decode's limits call it malformed.
    repeated = b"\xde\x00\x2e" + buf[1:] + b"\xa3seq\x07" * 40
    yield "a key repeated past the map limit", repeated
    yield "seq as uint32", buf.replace(b"\xa3seq\x2a", b"\xa3seq\xce" + struct.pack(">I", 42))


@pytest.mark.parametrize("index", range(8))
def test_other_encodings_are_left_to_msgpack(index: int) -> None:
    from tests.unit.test_wire import golden_frame

    name, buf = list(_variants(encode(golden_frame())))[index]
    assert canonical_frame(buf) is None, name
    got, want = outcome(buf), without_canonical(buf)
    if isinstance(want, Frame):
        assert isinstance(got, Frame)
        assert_identical(got, want)
    else:
        assert got == want, name


def test_other_messages_are_left_to_msgpack() -> None:
    from tests.unit.test_wire import golden_hello

    assert canonical_frame(encode(golden_hello())) is None
    assert canonical_frame(b"") is None and canonical_frame(b"\xc1") is None


def test_off_without_msgspec(monkeypatch: pytest.MonkeyPatch) -> None:
    from tests.unit.test_wire import golden_frame

    monkeypatch.setattr(wire_canonical, "ENABLED", False)
    buf = encode(golden_frame())
    assert canonical_frame(buf) is None
    decoded = decode(buf)
    assert isinstance(decoded, Frame)
    assert_identical(decoded, decode_frame_precisely(raw_of(golden_frame())))
