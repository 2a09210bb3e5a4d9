"""Wire codec (protocol v1): round trips, golden bytes, every rejection rule of ``decode``.

The rules and reason tags asserted here are the ones listed in ``docs/protocol.md`` §5; the
golden files in ``tests/data`` are the bytes shown in its annotated dump. Regenerate the golden
files (only after a deliberate format change, which needs a new protocol version) with::

    SKELFUSE_REGEN_GOLDEN=1 python -m pytest tests/unit/test_wire.py
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import re
import struct
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from skelfuse.protocol.constants import MAX_BODIES, MAX_MESSAGE_BYTES, PROTOCOL_VERSION
from skelfuse.protocol.errors import DecodeError, VersionMismatch
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.wire import (
    Body,
    Bye,
    ErrorMessage,
    Frame,
    Heartbeat,
    Hello,
    Message,
    Request,
    Response,
    Welcome,
    decode,
    encode,
)

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
DOC = ROOT / "docs" / "protocol.md"

NAN = float("nan")
INF = float("inf")
TRK = int(TrackingState.TRACKED)
INFD = int(TrackingState.INFERRED)
NOTR = int(TrackingState.NOT_TRACKED)


# --- fixed messages (the golden files and the doc's hex dump are made from these) -----------

GOLDEN_JOINTS = (
    (0.10, 0.20, 2.50, TRK),  # SpineBase
    (0.10, 0.50, 2.52, TRK),  # SpineMid
    (0.10, 0.85, 2.52, TRK),  # Neck
    (0.10, 0.98, 2.50, TRK),  # Head
    (-0.08, 0.75, 2.52, TRK),  # ShoulderLeft
    (-0.15, 0.48, 2.54, TRK),  # ElbowLeft
    (-0.18, 0.24, 2.50, TRK),  # WristLeft
    (-0.19, 0.17, 2.48, TRK),  # HandLeft
    (0.28, 0.75, 2.52, TRK),  # ShoulderRight
    (0.35, 0.48, 2.54, TRK),  # ElbowRight
    (0.38, 0.24, 2.50, TRK),  # WristRight
    (0.39, 0.17, 2.48, INFD),  # HandRight
    (0.02, 0.18, 2.50, TRK),  # HipLeft
    (0.01, -0.25, 2.48, TRK),  # KneeLeft
    (0.00, -0.68, 2.52, TRK),  # AnkleLeft
    (0.00, -0.75, 2.42, INFD),  # FootLeft
    (0.18, 0.18, 2.50, TRK),  # HipRight
    (0.19, -0.25, 2.48, TRK),  # KneeRight
    (0.20, -0.68, 2.52, TRK),  # AnkleRight
    (0.20, -0.75, 2.42, INFD),  # FootRight
    (0.10, 0.77, 2.52, TRK),  # SpineShoulder
    (-0.20, 0.09, 2.47, TRK),  # HandTipLeft
    (-0.16, 0.15, 2.45, INFD),  # ThumbLeft
    (NAN, NAN, NAN, NOTR),  # HandTipRight
    (NAN, NAN, NAN, NOTR),  # ThumbRight
)
GOLDEN_TRACKING_ID = 72057594037927941  # a Kinect v2-like id: needs a uint64 on the wire


def golden_frame() -> Frame:
    joints = np.array([row[:3] for row in GOLDEN_JOINTS], dtype=np.float32)
    states = np.array([row[3] for row in GOLDEN_JOINTS], dtype=np.uint8)
    return Frame(
        seq=42,
        t_capture_ns=1_700_000_000_123_456_789,
        bodies=(Body(tracking_id=GOLDEN_TRACKING_ID, joints_m=joints, states=states),),
        floor=(0.0, 1.0, 0.0, 0.8),
    )


def golden_hello() -> Hello:
    # Sensor at (-2, 1.2, 0.5) in the world, yaw 90° (looking along world +X): exact entries.
    pose = np.array(
        [[0.0, 0.0, 1.0, -2.0], [0.0, 1.0, 0.0, 1.2], [-1.0, 0.0, 0.0, 0.5], [0.0, 0.0, 0.0, 1.0]]
    )
    return Hello(
        sensor_id="kinect-a",
        sensor_type="kinect_v2",
        agent_version="0.1.0",
        fps=30.0,
        t_ns=1_700_000_000_000_000_000,
        pose_hint=pose,
        pose_hint_source="manual",
    )


def golden_bytes(name: str, generated: bytes) -> bytes:
    """The committed golden file ``tests/data/<name>``; rewritten only when asked to."""
    path = DATA / name
    if os.environ.get("SKELFUSE_REGEN_GOLDEN") == "1":
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(generated)
    if not path.exists():
        pytest.fail(f"golden file {path} is missing; regenerate with SKELFUSE_REGEN_GOLDEN=1")
    return path.read_bytes()


# --- helpers ------------------------------------------------------------------------------------


def assert_same(actual: object, expected: object, where: str = "message") -> None:
    """Field-by-field equality; numpy arrays compare exactly (NaN equals NaN) with dtype."""
    if isinstance(expected, np.ndarray):
        assert isinstance(actual, np.ndarray), where
        assert actual.dtype == expected.dtype, f"{where}: dtype {actual.dtype}"
        assert actual.shape == expected.shape, f"{where}: shape {actual.shape}"
        np.testing.assert_array_equal(actual, expected, err_msg=where)
    elif dataclasses.is_dataclass(expected) and not isinstance(expected, type):
        assert type(actual) is type(expected), f"{where}: {type(actual)}"
        for f in dataclasses.fields(expected):
            if f.compare:  # Frame.stacked: the decoder's arrays, not part of the message
                assert_same(getattr(actual, f.name), getattr(expected, f.name), f"{where}.{f.name}")
    elif isinstance(expected, tuple | list):
        assert type(actual) is type(expected), f"{where}: {type(actual)}"
        assert isinstance(actual, tuple | list)
        assert len(actual) == len(expected), where
        for i, (a, e) in enumerate(zip(actual, expected, strict=True)):
            assert_same(a, e, f"{where}[{i}]")
    elif isinstance(expected, float) and math.isnan(expected):
        assert isinstance(actual, float), where
        assert math.isnan(actual), where
    else:
        assert type(actual) is type(expected), f"{where}: {type(actual)} != {type(expected)}"
        assert actual == expected, f"{where}: {actual!r} != {expected!r}"


def make_body(tracking_id: int, rng: np.random.Generator, states: np.ndarray | None = None) -> Body:
    joints = rng.uniform(-2.0, 4.0, size=(JOINT_COUNT, 3)).astype(np.float32)
    if states is None:
        states = np.full(JOINT_COUNT, TRK, dtype=np.uint8)
    joints[states == NOTR] = np.nan  # what decode normalises NOT_TRACKED joints to
    return Body(tracking_id=tracking_id, joints_m=joints, states=states.astype(np.uint8))


def pack(raw: object) -> bytes:
    packed: bytes = msgpack.packb(raw, use_bin_type=True)
    return packed


def raw_body(tracking_id: int = 7, **changes: Any) -> dict[str, Any]:
    joints = np.tile(np.array([0.1, 0.9, 2.5], dtype="<f4"), (JOINT_COUNT, 1))
    body: dict[str, Any] = {
        "id": tracking_id,
        "joints": joints.tobytes(),
        "states": bytes([TRK] * JOINT_COUNT),
    }
    body.update(changes)
    return body


def raw_frame(**changes: Any) -> dict[str, Any]:
    frame: dict[str, Any] = {
        "v": 1,
        "type": "frame",
        "seq": 1,
        "t_capture_ns": 1_700_000_000_000_000_000,
        "bodies": [raw_body()],
        "floor": [0.0, 1.0, 0.0, 0.8],
    }
    frame.update(changes)
    return frame


def raw_hello(**changes: Any) -> dict[str, Any]:
    hello: dict[str, Any] = {
        "v": 1,
        "type": "hello",
        "sensor_id": "kinect-a",
        "sensor_type": "kinect_v2",
        "skeleton": "kinect_v2_25",
        "agent_version": "0.1.0",
        "fps": 30.0,
        "t_ns": 1_700_000_000_000_000_000,
    }
    hello.update(changes)
    return hello


RIGID_POSE = [1.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 1.2, 0.0, 0.0, 1.0, -3.0, 0.0, 0.0, 0.0, 1.0]

RAW_VALID: dict[str, dict[str, Any]] = {
    "frame": raw_frame(),
    "hello": raw_hello(pose_hint={"T_world_from_sensor": RIGID_POSE, "source": "sim_truth"}),
    "welcome": {
        "v": 1,
        "type": "welcome",
        "server_version": "0.1.0",
        "heartbeat_interval_s": 1.0,
        "t_ns": 5,
    },
    "heartbeat": {"v": 1, "type": "heartbeat", "t_ns": 5},
    "request": {"v": 1, "type": "request", "id": 3, "method": "depth_cloud", "params": {}},
    "response_ok": {"v": 1, "type": "response", "id": 3, "ok": True, "result": [1, 2]},
    "response_err": {"v": 1, "type": "response", "id": 3, "ok": False, "error": "no such method"},
    "error": {"v": 1, "type": "error", "code": "not_registered", "message": "send hello"},
    "bye": {"v": 1, "type": "bye"},
}

REQUIRED_FIELDS = [
    ("frame", "seq"),
    ("frame", "t_capture_ns"),
    ("frame", "bodies"),
    ("hello", "sensor_id"),
    ("hello", "sensor_type"),
    ("hello", "skeleton"),
    ("hello", "agent_version"),
    ("hello", "fps"),
    ("hello", "t_ns"),
    ("welcome", "server_version"),
    ("welcome", "heartbeat_interval_s"),
    ("welcome", "t_ns"),
    ("heartbeat", "t_ns"),
    ("request", "id"),
    ("request", "method"),
    ("request", "params"),
    ("response_ok", "id"),
    ("response_ok", "ok"),
    ("response_err", "id"),
    ("response_err", "error"),
    ("error", "code"),
    ("error", "message"),
]


def reject(buf: bytes | dict[str, Any] | list[Any], reason: str) -> DecodeError:
    data = buf if isinstance(buf, bytes) else pack(buf)
    with pytest.raises(DecodeError) as info:
        decode(data)
    assert info.value.reason == reason, f"expected {reason!r}: {info.value}"
    return info.value


def with_body(**changes: Any) -> dict[str, Any]:
    return raw_frame(bodies=[raw_body(**changes)])


def joints_with(index: int, value: tuple[float, float, float]) -> bytes:
    joints = np.tile(np.array([0.1, 0.9, 2.5], dtype="<f4"), (JOINT_COUNT, 1))
    joints[index] = value
    return joints.tobytes()


def states_with(index: int, state: int) -> bytes:
    states = [TRK] * JOINT_COUNT
    states[index] = state
    return bytes(states)


# --- round trips --------------------------------------------------------------------------------


def _round_trip_cases() -> list[tuple[str, Message]]:
    rng = np.random.default_rng(1)
    mixed = np.array([TRK, INFD, NOTR, TRK, INFD] * 5, dtype=np.uint8)
    six = tuple(make_body(1000 + i, rng) for i in range(MAX_BODIES))
    return [
        ("frame_0_bodies_no_floor", Frame(seq=0, t_capture_ns=0, bodies=())),
        (
            "frame_1_body_floor",
            Frame(
                seq=1,
                t_capture_ns=1_700_000_000_000_000_001,
                bodies=(make_body(2**64 - 1, rng, mixed),),
                floor=(0.0, 0.9986295347545738, 0.05233595624294383, 0.75),
            ),
        ),
        ("frame_6_bodies", Frame(seq=2**63 - 1, t_capture_ns=7, bodies=six, floor=None)),
        (
            "hello_plain",
            Hello(
                sensor_id="a",
                sensor_type="sim",
                agent_version="dev",
                fps=30.0,
                t_ns=1,
            ),
        ),
        (
            "hello_pose_hint",
            Hello(
                sensor_id="Kinect_1.left-2",
                sensor_type="azure_kinect",
                agent_version="0.1.0",
                fps=15.0,
                t_ns=2,
                pose_hint=np.array(
                    [[0, 0, 1, 1.5], [0, 1, 0, 1.0], [-1, 0, 0, -2.0], [0, 0, 0, 1]],
                    dtype=np.float64,
                ),
                pose_hint_source="sim_truth",
            ),
        ),
        ("welcome", Welcome(server_version="0.1.0", heartbeat_interval_s=1.0, t_ns=3)),
        ("heartbeat", Heartbeat(t_ns=4)),
        (
            "request",
            Request(request_id=9, method="depth_cloud", params={"frames": 3, "mode": "nfov"}),
        ),
        ("request_no_params", Request(request_id=0, method="ping")),
        ("response_ok", Response(request_id=9, ok=True, result={"points": b"\x00" * 12})),
        ("response_ok_nil", Response(request_id=9, ok=True)),
        ("response_error", Response(request_id=9, ok=False, error="unknown method 'x'")),
        ("error", ErrorMessage(code="not_registered", message="send hello first")),
        ("bye", Bye()),
    ]


ROUND_TRIP_CASES = _round_trip_cases()


@pytest.mark.parametrize(
    ("name", "message"), ROUND_TRIP_CASES, ids=[c[0] for c in ROUND_TRIP_CASES]
)
def test_round_trip(name: str, message: Message) -> None:
    data = encode(message)
    assert isinstance(data, bytes)
    decoded = decode(data)
    assert_same(decoded, message, name)
    assert encode(decoded) == data


def test_every_message_type_is_covered() -> None:
    covered = {type(m) for _, m in ROUND_TRIP_CASES}
    assert covered == {Hello, Welcome, Frame, Heartbeat, Request, Response, ErrorMessage, Bye}


def test_every_message_carries_version_and_type() -> None:
    for name, message in ROUND_TRIP_CASES:
        raw = msgpack.unpackb(encode(message), raw=False)
        assert isinstance(raw, dict), name
        assert all(isinstance(k, str) for k in raw), name
        assert raw["v"] == PROTOCOL_VERSION, name
        assert isinstance(raw["type"], str), name
        assert list(raw)[:2] == ["v", "type"], name


def test_decoded_arrays_are_writable_copies() -> None:
    frame = decode(encode(golden_frame()))
    assert isinstance(frame, Frame)
    joints, states = frame.bodies[0].joints_m, frame.bodies[0].states
    assert joints.flags.writeable
    assert states.flags.writeable
    assert joints.dtype == np.float32
    assert states.dtype == np.uint8


def test_frame_floor_absent_is_encoded_as_nil_and_may_be_omitted() -> None:
    raw = msgpack.unpackb(encode(Frame(seq=1, t_capture_ns=2, bodies=())), raw=False)
    assert raw["floor"] is None
    del raw["floor"]
    decoded = decode(pack(raw))
    assert isinstance(decoded, Frame)
    assert decoded.floor is None


def test_unknown_keys_are_ignored() -> None:
    raw = raw_frame(extra="from a newer minor revision")
    raw["bodies"][0]["hand_state"] = 2
    decoded = decode(pack(raw))
    assert isinstance(decoded, Frame)
    assert decoded.bodies[0].tracking_id == 7


def test_numbers_accept_any_msgpack_width() -> None:
    # float fields accept integers and float32; integer fields accept any int encoding.
    raw = raw_hello(fps=30)
    hello = decode(pack(raw))
    assert isinstance(hello, Hello)
    assert hello.fps == 30.0
    assert isinstance(hello.fps, float)
    f32 = msgpack.packb(raw_hello(fps=29.97), use_bin_type=True, use_single_float=True)
    hello32 = decode(f32)
    assert isinstance(hello32, Hello)
    assert hello32.fps == pytest.approx(29.97, rel=1e-6)


def test_not_tracked_joints_are_normalised_to_nan() -> None:
    joints = np.full((JOINT_COUNT, 3), 1.0, dtype=np.float32)
    joints[3] = (1000.0, -1000.0, 0.0)  # far out of range, but NOT_TRACKED: no meaning
    joints[4] = (NAN, NAN, NAN)
    states = np.full(JOINT_COUNT, TRK, dtype=np.uint8)
    states[[3, 4]] = NOTR
    frame = Frame(seq=1, t_capture_ns=1, bodies=(Body(5, joints, states),))
    decoded = decode(encode(frame))
    assert isinstance(decoded, Frame)
    out = decoded.bodies[0].joints_m
    assert np.isnan(out[[3, 4]]).all()
    np.testing.assert_array_equal(np.delete(out, [3, 4], axis=0), 1.0)


# --- determinism and golden bytes -------------------------------------------------------------


def test_encode_is_deterministic() -> None:
    for name, message in ROUND_TRIP_CASES:
        assert encode(message) == encode(message), name
    assert encode(golden_frame()) == encode(golden_frame())
    assert encode(golden_hello()) == encode(golden_hello())


def test_encode_does_not_depend_on_array_layout() -> None:
    frame = golden_frame()
    body = frame.bodies[0]
    fortran = Body(
        body.tracking_id,
        np.asfortranarray(body.joints_m.astype(">f4")),
        body.states.astype(np.int64),
    )
    assert encode(dataclasses.replace(frame, bodies=(fortran,))) == encode(frame)


def test_golden_frame() -> None:
    fixed = golden_frame()
    golden = golden_bytes("frame_v1.bin", encode(fixed))
    assert encode(fixed) == golden
    assert_same(decode(golden), fixed, "frame_v1")


def test_golden_hello() -> None:
    fixed = golden_hello()
    golden = golden_bytes("hello_v1.bin", encode(fixed))
    assert encode(fixed) == golden
    assert_same(decode(golden), fixed, "hello_v1")


def _doc_hex_dump(name: str) -> bytes:
    text = DOC.read_text(encoding="utf-8")
    match = re.search(
        rf"<!-- hexdump:{re.escape(name)} -->\n```text\n(.*?)```", text, flags=re.DOTALL
    )
    assert match, f"docs/protocol.md has no hex dump block for {name}"
    out = bytearray()
    for line in match.group(1).splitlines():
        row = re.match(r"^([0-9a-f]{4})  ((?:[0-9a-f]{2} )*[0-9a-f]{2})(?:\s|$)", line)
        if row is None:
            continue
        assert int(row.group(1), 16) == len(out), f"offset column wrong at {line!r}"
        out += bytes.fromhex(row.group(2))
    return bytes(out)


def test_doc_hex_dump_is_the_golden_frame() -> None:
    assert _doc_hex_dump("frame_v1") == golden_bytes("frame_v1.bin", encode(golden_frame()))


# --- an independent implementation of the documented format ----------------------------------


class _Writer:
    """A msgpack writer built from the byte layouts in docs/protocol.md §3 (no msgpack lib)."""

    def __init__(self) -> None:
        self.out = bytearray()

    def value(self, v: object) -> None:
        if v is None:
            self.out += b"\xc0"
        elif isinstance(v, bool):
            self.out += b"\xc3" if v else b"\xc2"
        elif isinstance(v, int):
            self.uint(v)
        elif isinstance(v, float):
            self.out += b"\xcb" + struct.pack(">d", v)
        elif isinstance(v, str):
            data = v.encode("utf-8")
            if len(data) < 32:
                self.out += bytes([0xA0 | len(data)])
            else:
                self.out += b"\xd9" + bytes([len(data)])
            self.out += data
        elif isinstance(v, bytes):
            header = (
                b"\xc4" + bytes([len(v)]) if len(v) < 256 else b"\xc5" + struct.pack(">H", len(v))
            )
            self.out += header + v
        elif isinstance(v, list):
            assert len(v) < 16
            self.out += bytes([0x90 | len(v)])
            for item in v:
                self.value(item)
        elif isinstance(v, dict):
            assert len(v) < 16
            self.out += bytes([0x80 | len(v)])
            for key, item in v.items():
                self.value(key)
                self.value(item)
        else:
            raise TypeError(type(v))

    def uint(self, v: int) -> None:
        assert v >= 0
        if v < 128:
            self.out += bytes([v])
        elif v < 2**8:
            self.out += b"\xcc" + struct.pack(">B", v)
        elif v < 2**16:
            self.out += b"\xcd" + struct.pack(">H", v)
        elif v < 2**32:
            self.out += b"\xce" + struct.pack(">I", v)
        else:
            self.out += b"\xcf" + struct.pack(">Q", v)


def _independent_frame_bytes() -> bytes:
    joints = b"".join(struct.pack("<3f", x, y, z) for x, y, z, _ in GOLDEN_JOINTS)
    states = bytes(int(s) for *_, s in GOLDEN_JOINTS)
    writer = _Writer()
    writer.value(
        {
            "v": 1,
            "type": "frame",
            "seq": 42,
            "t_capture_ns": 1_700_000_000_123_456_789,
            "bodies": [{"id": GOLDEN_TRACKING_ID, "joints": joints, "states": states}],
            "floor": [0.0, 1.0, 0.0, 0.8],
        }
    )
    return bytes(writer.out)


def test_independent_writer_matches_golden_bytes() -> None:
    assert _independent_frame_bytes() == golden_bytes("frame_v1.bin", encode(golden_frame()))


def test_independent_frame_decodes() -> None:
    decoded = decode(_independent_frame_bytes())
    assert_same(decoded, golden_frame(), "independent frame")


def test_raw_msgpack_frame_as_documented_decodes() -> None:
    # Built from the documented schema with a generic msgpack library, keys in another order,
    # single-precision floor, integers for a float field.
    joints = [(0.01 * i, 1.0 - 0.02 * i, 2.0 + 0.01 * i) for i in range(JOINT_COUNT)]
    states = [2] * 23 + [1, 0]
    joints[24] = (NAN, NAN, NAN)
    message = {
        "floor": [0, 1, 0, 1],
        "bodies": [
            {
                "states": bytes(states),
                "joints": b"".join(struct.pack("<fff", *p) for p in joints),
                "id": 2**63 + 5,
            },
            {
                "id": 1,
                "joints": struct.pack("<75f", *([0.5] * 75)),
                "states": b"\x01" * 25,
            },
        ],
        "t_capture_ns": 1_700_000_000_000_000_000,
        "seq": 300,
        "type": "frame",
        "v": 1,
    }
    data = msgpack.packb(message, use_bin_type=True, use_single_float=True)
    decoded = decode(data)
    assert isinstance(decoded, Frame)
    assert decoded.seq == 300
    assert decoded.t_capture_ns == 1_700_000_000_000_000_000
    assert decoded.floor == (0.0, 1.0, 0.0, 1.0)
    first, second = decoded.bodies
    assert first.tracking_id == 2**63 + 5
    expected = np.array(joints, dtype=np.float32)
    np.testing.assert_array_equal(first.joints_m, expected)
    np.testing.assert_array_equal(first.states, states)
    assert second.tracking_id == 1
    np.testing.assert_array_equal(second.joints_m, np.full((25, 3), 0.5, dtype=np.float32))
    np.testing.assert_array_equal(second.states, np.ones(25, dtype=np.uint8))


def test_joint_layout_is_row_major_xyz() -> None:
    joints = (np.arange(JOINT_COUNT * 3).reshape(JOINT_COUNT, 3) / 100).astype(np.float32)
    frame = Frame(seq=1, t_capture_ns=1, bodies=(Body(1, joints, np.full(25, 2, np.uint8)),))
    raw = msgpack.unpackb(encode(frame), raw=False)
    blob = raw["bodies"][0]["joints"]
    assert isinstance(blob, bytes)
    assert len(blob) == 300
    # joint j, axis a lives at byte offset 12*j + 4*a, little-endian float32
    for j in (0, 7, 24):
        for a in range(3):
            (value,) = struct.unpack_from("<f", blob, 12 * j + 4 * a)
            assert value == joints[j, a]


# --- rejection rules ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "buf",
    [
        b"",
        b"\xc1",  # the one byte msgpack never uses
        b"\x85\xa1v\x01",  # truncated map
        pack({"v": 1, "type": "bye"}) + b"\x00",  # trailing bytes
        b"\xff" * 100,
        bytes(range(256)),
    ],
    ids=["empty", "never_used", "truncated", "trailing", "ff", "ramp"],
)
def test_garbage_bytes(buf: bytes) -> None:
    reject(buf, "malformed")


@pytest.mark.parametrize("raw", [[1, 2], 5, "frame", None, True, b"\x01"])
def test_non_map(raw: object) -> None:
    reject(pack(raw), "malformed")


def test_invalid_utf8_string() -> None:
    reject(b"\x82\xa1v\x01\xa4typ\xff", "malformed")


def test_non_string_map_key() -> None:
    reject(pack({"v": 1, "type": "bye", 3: "x"}), "malformed")


def test_ext_type() -> None:
    reject(pack({"v": 1, "type": "bye", "x": msgpack.ExtType(1, b"ab")}), "malformed")


@pytest.mark.parametrize("version", [2, 0, -1, "1", None, [1], 2**64 - 1])
def test_wrong_version(version: object) -> None:
    error = reject({"v": version, "type": "heartbeat", "t_ns": 1}, "version")
    assert isinstance(error, VersionMismatch)
    assert error.received == version
    assert error.supported == PROTOCOL_VERSION


def test_missing_version() -> None:
    error = reject({"type": "heartbeat", "t_ns": 1}, "version")
    assert isinstance(error, VersionMismatch)


def test_bool_version() -> None:
    error = reject({"v": True, "type": "heartbeat", "t_ns": 1}, "version")
    assert isinstance(error, VersionMismatch)


def test_float_version() -> None:
    reject({"v": 1.0, "type": "heartbeat", "t_ns": 1}, "version")


def test_version_is_checked_before_type() -> None:
    reject({"v": 2, "type": "no_such_type"}, "version")


@pytest.mark.parametrize("kind", ["bodies", "Frame", "", 1, None, b"frame", "skeleton"])
def test_unknown_type(kind: object) -> None:
    reject({"v": 1, "type": kind}, "unknown_type")


def test_missing_type() -> None:
    reject({"v": 1}, "unknown_type")


@pytest.mark.parametrize(
    ("case", "name"), REQUIRED_FIELDS, ids=[f"{c}.{n}" for c, n in REQUIRED_FIELDS]
)
def test_missing_field(case: str, name: str) -> None:
    raw = copy.deepcopy(RAW_VALID[case])
    decode(pack(raw))  # valid as given
    del raw[name]
    reject(raw, "bad_field")


@pytest.mark.parametrize("name", ["id", "joints", "states"])
def test_missing_body_field(name: str) -> None:
    body = raw_body()
    del body[name]
    reject(raw_frame(bodies=[body]), "bad_field")


@pytest.mark.parametrize("name", ["T_world_from_sensor", "source"])
def test_missing_pose_hint_field(name: str) -> None:
    hint: dict[str, Any] = {"T_world_from_sensor": RIGID_POSE, "source": "manual"}
    del hint[name]
    reject(raw_hello(pose_hint=hint), "bad_field")


@pytest.mark.parametrize(
    ("case", "name", "value"),
    [
        ("frame", "seq", 1.0),
        ("frame", "seq", "1"),
        ("frame", "seq", True),
        ("frame", "seq", None),
        ("frame", "t_capture_ns", 1.7e18),
        ("frame", "bodies", {}),
        ("frame", "bodies", None),
        ("frame", "bodies", b""),
        ("hello", "sensor_id", b"kinect-a"),
        ("hello", "sensor_id", 5),
        ("hello", "sensor_type", None),
        ("hello", "skeleton", 25),
        ("hello", "agent_version", 1),
        ("hello", "fps", "30"),
        ("hello", "fps", True),
        ("hello", "t_ns", -0.5),
        ("hello", "pose_hint", [1, 0]),
        ("welcome", "server_version", None),
        ("welcome", "heartbeat_interval_s", "1"),
        ("heartbeat", "t_ns", "now"),
        ("heartbeat", "t_ns", False),
        ("request", "id", "3"),
        ("request", "method", 3),
        ("request", "params", [1]),
        ("request", "params", None),
        ("response_ok", "ok", 1),
        ("response_ok", "ok", "true"),
        ("response_ok", "id", 1.5),
        ("response_err", "error", None),
        ("error", "code", 404),
        ("error", "message", None),
    ],
)
def test_wrong_type(case: str, name: str, value: object) -> None:
    raw = copy.deepcopy(RAW_VALID[case])
    raw[name] = value
    reject(raw, "bad_field")


@pytest.mark.parametrize(
    "changes",
    [
        {"id": "7"},
        {"id": 7.0},
        {"id": True},
        {"joints": "x" * 300},  # str, not bin
        {"joints": [[0.0, 0.0, 0.0]] * 25},
        {"states": "\x02" * 25},
        {"states": [2] * 25},
    ],
    ids=["id_str", "id_float", "id_bool", "joints_str", "joints_array", "states_str", "states_arr"],
)
def test_body_wrong_type(changes: dict[str, Any]) -> None:
    reject(with_body(**changes), "bad_field")


@pytest.mark.parametrize("body", [[1, 2], "body", 7, None])
def test_body_not_a_map(body: object) -> None:
    reject(raw_frame(bodies=[body]), "bad_field")


@pytest.mark.parametrize(
    ("case", "name", "value"),
    [
        ("frame", "seq", -1),
        ("frame", "seq", 2**63),
        ("frame", "t_capture_ns", -1),
        ("hello", "t_ns", -5),
        ("welcome", "t_ns", 2**64 - 1),
        ("heartbeat", "t_ns", -(2**63)),
        ("request", "id", -1),
        ("response_ok", "id", 2**63),
    ],
)
def test_integer_out_of_range(case: str, name: str, value: int) -> None:
    raw = copy.deepcopy(RAW_VALID[case])
    raw[name] = value
    reject(raw, "out_of_range")


def test_integer_limits_accepted() -> None:
    frame = decode(pack(raw_frame(seq=2**63 - 1, t_capture_ns=0)))
    assert isinstance(frame, Frame)
    assert frame.seq == 2**63 - 1
    body = decode(pack(with_body(id=2**64 - 1)))
    assert isinstance(body, Frame)
    assert body.bodies[0].tracking_id == 2**64 - 1
    body0 = decode(pack(with_body(id=0)))
    assert isinstance(body0, Frame)
    assert body0.bodies[0].tracking_id == 0


def test_tracking_id_negative() -> None:
    reject(with_body(id=-1), "out_of_range")


@pytest.mark.parametrize("length", [0, 288, 299, 301, 400, 4096])
def test_joints_wrong_byte_length(length: int) -> None:
    reject(with_body(joints=b"\x00" * length), "bad_shape")


@pytest.mark.parametrize("length", [0, 1, 24, 26, 32])
def test_states_wrong_length(length: int) -> None:
    reject(with_body(states=b"\x02" * length), "bad_shape")


@pytest.mark.parametrize("state", [3, 4, 255])
def test_state_out_of_range(state: int) -> None:
    reject(with_body(states=states_with(11, state)), "out_of_range")


@pytest.mark.parametrize("state", [TRK, INFD])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_nan_in_tracked_or_inferred_joint(state: int, axis: int) -> None:
    point = [0.1, 0.2, 0.3]
    point[axis] = NAN
    joints = joints_with(5, (point[0], point[1], point[2]))
    reject(with_body(joints=joints, states=states_with(5, state)), "non_finite")


def test_nan_in_not_tracked_joint_is_accepted_and_normalised() -> None:
    joints = joints_with(5, (NAN, 0.2, 0.3))
    decoded = decode(pack(with_body(joints=joints, states=states_with(5, NOTR))))
    assert isinstance(decoded, Frame)
    out = decoded.bodies[0].joints_m
    assert np.isnan(out[5]).all()
    assert np.isfinite(np.delete(out, 5, axis=0)).all()


def test_nan_payload_bits_in_not_tracked_joint_are_accepted() -> None:
    quiet_nan_with_payload = struct.unpack("<f", b"\x01\x00\xc0\x7f")[0]
    negative_nan = struct.unpack("<f", b"\x00\x00\xc0\xff")[0]
    joints = bytearray(joints_with(0, (0.0, 0.0, 0.0)))
    joints[12 * 6 : 12 * 6 + 8] = struct.pack("<2f", quiet_nan_with_payload, negative_nan)
    decoded = decode(pack(with_body(joints=bytes(joints), states=states_with(6, NOTR))))
    assert isinstance(decoded, Frame)
    assert np.isnan(decoded.bodies[0].joints_m[6]).all()


@pytest.mark.parametrize("state", [TRK, INFD, NOTR])
@pytest.mark.parametrize("value", [INF, -INF])
def test_infinity_anywhere(state: int, value: float) -> None:
    joints = joints_with(20, (0.0, value, 1.0))
    reject(with_body(joints=joints, states=states_with(20, state)), "non_finite")


@pytest.mark.parametrize("state", [TRK, INFD])
@pytest.mark.parametrize("point", [(50.01, 0.0, 1.0), (0.0, -60.0, 1.0), (0.0, 0.0, 1e30)])
def test_coordinate_beyond_50_m(state: int, point: tuple[float, float, float]) -> None:
    reject(with_body(joints=joints_with(2, point), states=states_with(2, state)), "out_of_range")


def test_coordinate_at_50_m_is_accepted() -> None:
    decoded = decode(pack(with_body(joints=joints_with(2, (50.0, -50.0, 50.0)))))
    assert isinstance(decoded, Frame)
    assert decoded.bodies[0].joints_m[2].tolist() == [50.0, -50.0, 50.0]


def test_far_not_tracked_joint_is_accepted_and_normalised() -> None:
    raw = with_body(joints=joints_with(2, (1e30, 0.0, 0.0)), states=states_with(2, NOTR))
    decoded = decode(pack(raw))
    assert isinstance(decoded, Frame)
    assert np.isnan(decoded.bodies[0].joints_m[2]).all()


def test_more_than_six_bodies() -> None:
    bodies = [raw_body(tracking_id=i) for i in range(MAX_BODIES + 1)]
    reject(raw_frame(bodies=bodies), "bad_shape")
    decoded = decode(pack(raw_frame(bodies=bodies[:MAX_BODIES])))
    assert isinstance(decoded, Frame)
    assert len(decoded.bodies) == MAX_BODIES


def test_body_count_is_checked_before_bodies() -> None:
    bodies: list[Any] = ["not a body"] * (MAX_BODIES + 1)
    reject(raw_frame(bodies=bodies), "bad_shape")


def test_duplicate_tracking_ids() -> None:
    reject(raw_frame(bodies=[raw_body(3), raw_body(4), raw_body(3)]), "bad_field")


@pytest.mark.parametrize(
    ("floor", "reason"),
    [
        ([0.0, 1.0, 0.0], "bad_shape"),
        ([0.0, 1.0, 0.0, 0.8, 0.0], "bad_shape"),
        ({"a": 0.0}, "bad_shape"),
        ("0 1 0 0.8", "bad_shape"),
        ([0.0, 2.0, 0.0, 0.8], "out_of_range"),
        ([0.0, 0.0, 0.0, 0.8], "out_of_range"),
        ([0.0, 1.0, 0.0, NAN], "non_finite"),
        ([0.0, INF, 0.0, 0.0], "non_finite"),
        ([0.0, "1", 0.0, 0.8], "bad_field"),
        ([0.0, True, 0.0, 0.8], "bad_field"),
    ],
)
def test_bad_floor(floor: object, reason: str) -> None:
    reject(raw_frame(floor=floor), reason)


def test_floor_normal_tolerance() -> None:
    ok = decode(pack(raw_frame(floor=[0.0, 1.0009, 0.0, 0.8])))
    assert isinstance(ok, Frame)
    reject(raw_frame(floor=[0.0, 1.0011, 0.0, 0.8]), "out_of_range")


def test_too_large_message() -> None:
    reject(b"\x00" * (MAX_MESSAGE_BYTES + 1), "too_large")
    big = pack({"v": 1, "type": "error", "code": "x", "message": "y", "pad": ["z" * 4000] * 17})
    assert len(big) > MAX_MESSAGE_BYTES
    reject(big, "too_large")


def test_message_of_exactly_the_limit_is_accepted() -> None:
    def request(last: int) -> bytes:
        params = {"pad": ["z" * 4096] * 15 + ["z" * last]}
        return pack({"v": 1, "type": "request", "id": 1, "method": "m", "params": params})

    size_without_last = len(request(0))
    data = request(MAX_MESSAGE_BYTES - size_without_last - 2)  # str16 header: 3 bytes, not 1
    assert len(data) == MAX_MESSAGE_BYTES
    assert isinstance(decode(data), Request)


@pytest.mark.parametrize(
    "raw",
    [
        {"v": 1, "type": "error", "code": "x", "message": "y" * 4097},  # str > 4096 bytes
        with_body(joints=b"\x00" * 4097),  # bin > 4096 bytes
        raw_frame(bodies=[raw_body(i) for i in range(65)]),  # array > 64 items
        {"v": 1, "type": "bye", **{f"k{i}": i for i in range(31)}},  # map > 32 entries
    ],
    ids=["str", "bin", "array", "map"],
)
def test_msgpack_container_limits(raw: dict[str, Any]) -> None:
    reject(raw, "malformed")


def test_msgpack_container_limits_boundary() -> None:
    assert isinstance(decode(pack({"v": 1, "type": "bye", **{f"k{i}": i for i in range(30)}})), Bye)
    message = "y" * 4096
    decoded = decode(pack({"v": 1, "type": "error", "code": "x", "message": message}))
    assert isinstance(decoded, ErrorMessage)
    assert decoded.message == message


@pytest.mark.parametrize(
    "sensor_id",
    [
        "",
        "-kinect",
        ".kinect",
        "_a",
        "a" * 65,
        "kinect a",
        "kinect/a",
        "kinect:a",
        "kinéct",
        "a\x00",
    ],
)
def test_bad_sensor_id(sensor_id: str) -> None:
    reject(raw_hello(sensor_id=sensor_id), "bad_field")


def test_sensor_id_with_trailing_newline() -> None:
    reject(raw_hello(sensor_id="kinect-a\n"), "bad_field")


@pytest.mark.parametrize("sensor_id", ["a", "7", "a" * 64, "Kinect_1.left-2", "femto-B.03"])
def test_good_sensor_id(sensor_id: str) -> None:
    hello = decode(pack(raw_hello(sensor_id=sensor_id)))
    assert isinstance(hello, Hello)
    assert hello.sensor_id == sensor_id


@pytest.mark.parametrize("sensor_type", ["kinect_v3", "Kinect_v2", "", "kinect"])
def test_unknown_sensor_type(sensor_type: str) -> None:
    reject(raw_hello(sensor_type=sensor_type), "bad_field")


@pytest.mark.parametrize("sensor_type", ["kinect_v2", "azure_kinect", "femto", "sim", "replay"])
def test_known_sensor_types(sensor_type: str) -> None:
    assert isinstance(decode(pack(raw_hello(sensor_type=sensor_type))), Hello)


@pytest.mark.parametrize("skeleton", ["k4abt_32", "kinect_v2", "", "KINECT_V2_25"])
def test_unsupported_skeleton(skeleton: str) -> None:
    reject(raw_hello(skeleton=skeleton), "bad_field")


@pytest.mark.parametrize(
    ("fps", "reason"),
    [
        (0, "out_of_range"),
        (-30.0, "out_of_range"),
        (240.5, "out_of_range"),
        (NAN, "non_finite"),
        (INF, "non_finite"),
    ],
)
def test_bad_fps(fps: float, reason: str) -> None:
    reject(raw_hello(fps=fps), reason)


def test_fps_limits() -> None:
    for fps in (0.001, 240, 240.0):
        assert isinstance(decode(pack(raw_hello(fps=fps))), Hello)


def test_agent_version_is_truncated_to_64_characters() -> None:
    hello = decode(pack(raw_hello(agent_version="x" * 100)))
    assert isinstance(hello, Hello)
    assert hello.agent_version == "x" * 64


def _pose(matrix: list[Any], source: object = "manual") -> dict[str, Any]:
    return raw_hello(pose_hint={"T_world_from_sensor": matrix, "source": source})


def _rot_z(deg: float) -> list[float]:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return [c, -s, 0.0, 1.0, s, c, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize(
    ("matrix", "reason"),
    [
        ([2.0 * x if i in (0, 5, 10) else x for i, x in enumerate(RIGID_POSE)], "bad_field"),
        ([-1.0 if i == 0 else x for i, x in enumerate(RIGID_POSE)], "bad_field"),  # reflection
        ([0.3 if i == 1 else x for i, x in enumerate(RIGID_POSE)], "bad_field"),  # shear
        ([0.1 if i == 12 else x for i, x in enumerate(RIGID_POSE)], "bad_field"),  # last row
        ([2.0 if i == 15 else x for i, x in enumerate(RIGID_POSE)], "bad_field"),  # last row
        ([0.0] * 16, "bad_field"),
        (RIGID_POSE[:15], "bad_shape"),
        ([*RIGID_POSE, 0.0], "bad_shape"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "bad_shape"),  # nested
        (["1", *RIGID_POSE[1:]], "bad_shape"),
        ([True, *RIGID_POSE[1:]], "bad_shape"),
        ([None, *RIGID_POSE[1:]], "bad_shape"),
        ([NAN, *RIGID_POSE[1:]], "non_finite"),
        ([*RIGID_POSE[:3], INF, *RIGID_POSE[4:]], "non_finite"),
    ],
    ids=[
        "scaled",
        "reflection",
        "shear",
        "last_row_x",
        "last_row_w",
        "zeros",
        "15",
        "17",
        "nested",
        "str",
        "bool",
        "nil",
        "nan",
        "inf",
    ],
)
def test_bad_pose_hint(matrix: list[Any], reason: str) -> None:
    reject(_pose(matrix), reason)


def test_pose_hint_with_huge_entries_is_a_decode_error() -> None:
    reject(_pose([1e200, *RIGID_POSE[1:]]), "bad_field")


@pytest.mark.parametrize("hint", [[1.0] * 16, "manual", 5])
def test_pose_hint_not_a_map(hint: object) -> None:
    reject(raw_hello(pose_hint=hint), "bad_field")


@pytest.mark.parametrize("source", ["truth", "", "MANUAL", None, 1])
def test_bad_pose_hint_source(source: object) -> None:
    reject(_pose(RIGID_POSE, source), "bad_field")


def test_good_pose_hint() -> None:
    hello = decode(pack(_pose(_rot_z(30.0), "sim_truth")))
    assert isinstance(hello, Hello)
    assert hello.pose_hint_source == "sim_truth"
    assert hello.pose_hint is not None
    assert hello.pose_hint.dtype == np.float64
    np.testing.assert_array_equal(hello.pose_hint, np.array(_rot_z(30.0)).reshape(4, 4))
    # Row-major: element 3 is the x translation.
    assert hello.pose_hint[0, 3] == 1.0
    integers = decode(pack(_pose([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1])))
    assert isinstance(integers, Hello)
    np.testing.assert_array_equal(integers.pose_hint, np.eye(4))


def test_pose_hint_nil_means_absent() -> None:
    hello = decode(pack(raw_hello(pose_hint=None)))
    assert isinstance(hello, Hello)
    assert hello.pose_hint is None
    assert hello.pose_hint_source is None


def test_response_ok_ignores_error_and_error_ignores_result() -> None:
    ok = decode(pack({"v": 1, "type": "response", "id": 1, "ok": True}))
    assert isinstance(ok, Response)
    assert ok.result is None
    failed = decode(
        pack({"v": 1, "type": "response", "id": 1, "ok": False, "error": "e", "result": 5})
    )
    assert isinstance(failed, Response)
    assert failed.result is None
    assert failed.error == "e"


def test_every_decode_error_has_a_documented_reason() -> None:
    text = DOC.read_text(encoding="utf-8")
    for reason in (
        "malformed",
        "too_large",
        "version",
        "unknown_type",
        "bad_field",
        "bad_shape",
        "non_finite",
        "out_of_range",
    ):
        assert f"`{reason}`" in text, reason
