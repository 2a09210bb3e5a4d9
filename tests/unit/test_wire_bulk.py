"""The bulk fast path of frame decoding (``protocol.wire_bulk``) against the precise checks.

``decode`` checks a ``frame`` in bulk first and runs the precise, ordered checks only when the
bulk path declines. These tests hold the two together:

- on generated frame maps, valid and broken in every documented way (docs/protocol.md §6.3),
  ``decode``'s frame step and the precise checks give the same Frame, bit for bit (arrays,
  dtypes, flags, NaN where NOT_TRACKED), or the same error type, reason and message;
- whatever the bulk path accepts, the precise checks accept with the same values;
- valid frames do take the bulk path (else the speed-up is gone without a failing test);
- each documented frame rejection still happens through ``decode``, and the bulk path declines it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import given, strategies as st

from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.wire import (
    Body,
    Frame,
    _decode_frame,
    decode,
    decode_frame_precisely,
    encode,
)
from skelfuse.protocol.wire_bulk import frame_in_bulk
from tests.unit.test_wire_properties import UINT63, UINT64, _junk_scalars, frames

_SPECIAL_FLOATS = [math.nan, -math.nan, math.inf, -math.inf, 50.0, -50.0, 50.000004, -50.000004,
                   1e30, 0.0, -0.0, 31.99, 32.0]  # fmt: skip


def raw_of(frame: Frame) -> dict[str, Any]:
    """The map ``decode`` hands to its frame step for ``encode(frame)``."""
    raw: dict[str, Any] = msgpack.unpackb(encode(frame), raw=False)
    return raw


def outcome(step: Callable[[dict[str, Any]], Frame], raw: dict[str, Any]) -> Frame | tuple:
    try:
        return step(raw)
    except DecodeError as exc:
        return (type(exc), exc.reason, str(exc))


def assert_identical(actual: Frame | tuple, expected: Frame | tuple) -> None:
    """Same error, or the same Frame down to array bytes (NaN payloads), dtypes and flags."""
    if isinstance(expected, tuple):
        assert actual == expected
        return
    assert isinstance(actual, Frame)
    assert (actual.seq, actual.t_capture_ns) == (expected.seq, expected.t_capture_ns)
    assert type(actual.seq) is int and type(actual.t_capture_ns) is int
    assert actual.floor == expected.floor
    assert actual.pose == expected.pose
    if expected.floor is not None:
        assert actual.floor is not None and all(type(x) is float for x in actual.floor)
    assert type(actual.bodies) is tuple and len(actual.bodies) == len(expected.bodies)
    for got, want in zip(actual.bodies, expected.bodies, strict=True):
        assert type(got) is Body and got.tracking_id == want.tracking_id
        for a, b in ((got.joints_m, want.joints_m), (got.states, want.states)):
            assert a.dtype == b.dtype and a.shape == b.shape
            assert a.flags.writeable and a.flags.c_contiguous and b.flags.c_contiguous
            assert a.tobytes() == b.tobytes()


# --- broken frame maps ----------------------------------------------------------------------


def _set(path: tuple[Any, ...], value: Any) -> Callable[[dict[str, Any]], None]:
    def apply(raw: dict[str, Any]) -> None:
        target: Any = raw
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return apply


def _delete(path: tuple[Any, ...]) -> Callable[[dict[str, Any]], None]:
    def apply(raw: dict[str, Any]) -> None:
        target: Any = raw
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]

    return apply


def _patch_blob(body: int, name: str, at: int, blob: bytes) -> Callable[[dict[str, Any]], None]:
    def apply(raw: dict[str, Any]) -> None:
        old = raw["bodies"][body][name]
        at_ = at % len(old) if old else 0
        raw["bodies"][body][name] = old[:at_] + blob + old[at_ + len(blob) :]

    return apply


@st.composite
def mutations(draw: st.DrawFn, raw: dict[str, Any]) -> Callable[[dict[str, Any]], None]:
    """One change that may break the frame map ``raw`` (or not: the tests compare, not expect)."""
    count = len(raw["bodies"]) if isinstance(raw.get("bodies"), list) else 0
    scalar = st.sampled_from(["seq", "t_capture_ns", "bodies", "floor"])
    choices = ["scalar", "delete", "floor"]
    if count:
        choices += ["body", "body_field", "body_delete", "joint", "joint", "state", "dup", "blob"]
    kind = draw(st.sampled_from(choices))
    junk = _junk_scalars | st.sampled_from([-1, UINT63 + 1, UINT64 + 1, [], {}, b"", "x"])
    body = draw(st.integers(0, max(count - 1, 0)))
    if kind == "scalar":
        return _set((draw(scalar),), draw(junk))
    if kind == "delete":
        return _delete((draw(scalar),)) if draw(st.booleans()) else _set(("bodies",), [{}] * 7)
    if kind == "floor":
        element = st.sampled_from([1.0, 0.0, 1, 0, True, math.nan, math.inf, 0.9, 1.0005, "1"])
        return _set(("floor",), draw(st.lists(element, min_size=3, max_size=5)))
    if kind == "body":
        return _set(("bodies", body), draw(junk))
    if kind == "body_field":
        field = draw(st.sampled_from(["id", "joints", "states"]))
        value = draw(junk | st.binary(max_size=310) | st.just(bytes(300)) | st.just(bytes(25)))
        return _set(("bodies", body, field), value)
    if kind == "body_delete":
        return _delete(("bodies", body, draw(st.sampled_from(["id", "joints", "states"]))))
    if kind == "joint":  # a special value in any coordinate, tracked or not
        value = np.array(draw(st.sampled_from(_SPECIAL_FLOATS)), dtype="<f4").tobytes()
        return _patch_blob(body, "joints", 4 * draw(st.integers(0, 74)), value)
    if kind == "state":
        value = bytes([draw(st.sampled_from([0, 0, 1, 2, 3, 255]))])
        return _patch_blob(body, "states", draw(st.integers(0, 24)), value)
    if kind == "dup":
        other = draw(st.integers(0, count - 1))

        def duplicate(raw: dict[str, Any]) -> None:
            raw["bodies"][body]["id"] = raw["bodies"][other]["id"]

        return duplicate
    return _patch_blob(body, "joints", draw(st.integers(0, 299)), draw(st.binary(max_size=8)))


@st.composite
def frame_maps(draw: st.DrawFn) -> dict[str, Any]:
    raw = raw_of(draw(frames()))
    for _ in range(draw(st.integers(0, 3))):
        change = draw(mutations(raw))
        with contextlib.suppress(TypeError, KeyError, IndexError):  # an earlier change
            change(raw)  # removed what this one edits
    return raw


# --- equivalence ------------------------------------------------------------------------------


@given(raw=frame_maps())
def test_decode_agrees_with_the_precise_checks(raw: dict[str, Any]) -> None:
    assert_identical(outcome(_decode_frame, raw), outcome(decode_frame_precisely, raw))


@given(raw=frame_maps())
def test_what_the_bulk_path_accepts_the_precise_checks_accept_alike(raw: dict[str, Any]) -> None:
    if frame_in_bulk(raw) is None:
        return
    precise = outcome(decode_frame_precisely, raw)
    assert isinstance(precise, Frame), f"bulk accepted what the precise checks refuse: {precise}"
    assert_identical(_decode_frame(raw), precise)


@given(frame=frames())
def test_valid_frames_take_the_bulk_path(frame: Frame) -> None:
    raw = raw_of(frame)
    assert frame_in_bulk(raw) is not None
    assert_identical(_decode_frame(raw), decode_frame_precisely(raw))


def test_floor_as_integers_and_no_bodies_take_the_bulk_path() -> None:
    raw = {"type": "frame", "seq": 0, "t_capture_ns": 0, "bodies": [], "floor": [0, 1, 0, 2]}
    assert frame_in_bulk(raw) is not None
    assert_identical(_decode_frame(raw), decode_frame_precisely(raw))


# --- every documented frame rejection (docs/protocol.md §6.3) --------------------------------


def _valid_raw() -> dict[str, Any]:
    rng = np.random.default_rng(3)
    bodies = []
    for k in range(3):
        joints = rng.uniform(-2.0, 3.0, (JOINT_COUNT, 3)).astype(np.float32)
        states = np.full(JOINT_COUNT, 2, dtype=np.uint8)
        states[[21, 23]] = 0
        joints[21] = np.nan
        bodies.append(Body(1000 + k, joints, states))
    return raw_of(Frame(7, 1_700_000_000_000_000_000, tuple(bodies), (0.0, 1.0, 0.0, 0.8)))


def _joint(body: int, joint: int, axis: int, value: float) -> Callable[[dict[str, Any]], None]:
    return _patch_blob(body, "joints", 12 * joint + 4 * axis, np.float32(value).tobytes())


REJECTIONS: list[tuple[str, Callable[[dict[str, Any]], None], str]] = [
    ("seq missing", _delete(("seq",)), "bad_field"),
    ("seq a float", _set(("seq",), 7.0), "bad_field"),
    ("seq a bool", _set(("seq",), True), "bad_field"),
    ("seq negative", _set(("seq",), -1), "out_of_range"),
    ("t_capture_ns 2^63", _set(("t_capture_ns",), UINT63 + 1), "out_of_range"),
    ("bodies a map", _set(("bodies",), {}), "bad_field"),
    ("seven bodies", _set(("bodies",), [{}] * 7), "bad_shape"),
    ("body a list", _set(("bodies", 1), []), "bad_field"),
    ("id missing", _delete(("bodies", 0, "id")), "bad_field"),
    ("id a bool", _set(("bodies", 0, "id"), False), "bad_field"),
    ("id negative", _set(("bodies", 0, "id"), -5), "out_of_range"),
    ("id -2^63", _set(("bodies", 0, "id"), -(2**63)), "out_of_range"),
    ("joints a str", _set(("bodies", 0, "joints"), "x" * 300), "bad_field"),
    ("joints a list", _set(("bodies", 0, "joints"), [0.0] * 10), "bad_field"),
    ("joints 296 bytes", _set(("bodies", 2, "joints"), bytes(296)), "bad_shape"),
    ("states 24 bytes", _set(("bodies", 2, "states"), bytes(24)), "bad_shape"),
    ("states missing", _delete(("bodies", 1, "states")), "bad_field"),
    ("state 3", _patch_blob(1, "states", 5, b"\x03"), "out_of_range"),
    ("NaN in a tracked joint", _joint(2, 4, 1, math.nan), "non_finite"),
    ("inf in a tracked joint", _joint(2, 4, 2, math.inf), "non_finite"),
    ("inf in a NOT_TRACKED joint", _joint(1, 23, 0, -math.inf), "non_finite"),
    ("tracked joint 50.000004 m", _joint(0, 0, 2, 50.000004), "out_of_range"),
    ("tracked joint -50.000004 m", _joint(0, 0, 0, -50.000004), "out_of_range"),
    ("duplicate ids", _set(("bodies", 2, "id"), 1000), "bad_field"),
    ("floor of 3", _set(("floor",), [0.0, 1.0, 0.0]), "bad_shape"),
    ("floor a map", _set(("floor",), {}), "bad_shape"),
    ("floor with a bool", _set(("floor",), [0.0, True, 0.0, 1.0]), "bad_field"),
    ("floor with NaN", _set(("floor",), [0.0, 1.0, 0.0, math.nan]), "non_finite"),
    ("floor normal not unit", _set(("floor",), [0.0, 1.0011, 0.0, 1.0]), "out_of_range"),
]


@pytest.mark.parametrize(("name", "change", "reason"), REJECTIONS, ids=[r[0] for r in REJECTIONS])
def test_each_documented_frame_rejection_still_happens(
    name: str, change: Callable[[dict[str, Any]], None], reason: str
) -> None:
    raw = _valid_raw()
    assert frame_in_bulk(raw) is not None
    change(raw)
    assert frame_in_bulk(raw) is None
    with pytest.raises(DecodeError) as caught:
        decode(msgpack.packb(raw, use_bin_type=True))
    assert caught.value.reason == reason, str(caught.value)
    assert outcome(decode_frame_precisely, raw) == (type(caught.value), reason, str(caught.value))


def test_accepted_edges_stay_accepted() -> None:
    """±50.0 m exactly, anything finite or NaN where NOT_TRACKED: accepted by both paths."""
    raw = _valid_raw()
    for change in (
        _joint(0, 0, 0, 50.0),
        _joint(0, 1, 1, -50.0),
        _joint(1, 21, 0, 1e30),
        _joint(1, 23, 2, -3.0e38),
    ):
        change(raw)
    frame = decode(msgpack.packb(raw, use_bin_type=True))
    assert isinstance(frame, Frame) and frame_in_bulk(raw) is not None
    assert_identical(frame, decode_frame_precisely(raw))
    assert np.isnan(frame.bodies[1].joints_m[[21, 23]]).all()


# --- the decoder's stacked arrays (Frame.stacked) ---------------------------------------------


@given(frame=frames())
def test_a_decoded_frame_keeps_the_arrays_its_bodies_are_rows_of(frame: Frame) -> None:
    """``stacked`` is the bodies' own memory, row by row in body order: fusion reads it as the
    stack of the bodies' arrays without copying (fusion.sensors.TimedFrame.arrays)."""
    decoded = decode(encode(frame))
    assert isinstance(decoded, Frame)
    if not decoded.bodies:
        assert decoded.stacked is None
        return
    assert decoded.stacked is not None
    joints, states = decoded.stacked
    assert joints.shape == (len(decoded.bodies), JOINT_COUNT, 3) and joints.dtype == np.float32
    assert states.shape == (len(decoded.bodies), JOINT_COUNT) and states.dtype == np.uint8
    for row, body in enumerate(decoded.bodies):
        assert body.joints_m.base is joints and body.states.base is states
        assert np.shares_memory(joints[row], body.joints_m)
        np.testing.assert_array_equal(joints[row], body.joints_m)
        np.testing.assert_array_equal(states[row], body.states)


def test_frames_built_or_changed_otherwise_have_no_stacked_arrays() -> None:
    """Only the decoder sets ``stacked``: a frame built by hand, or replaced from a decoded one
    with other bodies, has None (the arrays would no longer be its bodies')."""
    raw = _valid_raw()
    decoded = decode(msgpack.packb(raw, use_bin_type=True))
    assert isinstance(decoded, Frame) and decoded.stacked is not None
    assert Frame(1, 2, decoded.bodies).stacked is None
    assert dataclasses.replace(decoded, bodies=decoded.bodies[:1]).stacked is None
    assert decoded == dataclasses.replace(decoded)  # not compared: equal frames stay equal
    assert decode_frame_precisely(raw).stacked is None
