"""Property tests of the wire codec's trust boundary, ``protocol.wire.decode`` (hypothesis).

- arbitrary bytes only ever raise ``DecodeError`` (never another exception);
- valid messages (frames with 0..6 bodies, finite joints within range, states 0..2, NaN allowed
  in NOT_TRACKED joints; every other message type too) survive ``encode``/``decode`` unchanged,
  with NOT_TRACKED positions normalised to NaN;
- valid messages with random byte flips, truncations, insertions and deletions decode to
  ``DecodeError`` or to a valid message;
- structure-aware garbage: msgpack maps with the right keys and wrong types, shapes and values
  raise ``DecodeError`` with a reason of the documented set (``docs/protocol.md`` §5) or decode
  to a valid message.

"Valid message" is checked by :func:`assert_valid`: the invariants ``decode`` promises, and a
re-encode that decodes to the same message.

Sizes: the ``ci`` profile (selected when the ``CI`` environment variable is set) runs 2 500
examples per test, 12 500 in all; locally the ``wire-dev`` profile runs 300 per test. Choose
another with ``pytest --hypothesis-profile=NAME``.
"""

from __future__ import annotations

import math
import os
from typing import Any

import msgpack
import numpy as np
import numpy.typing as npt
from hypothesis import HealthCheck, event, given, settings, strategies as st

from skelfuse.protocol.constants import (
    MAX_BODIES,
    MAX_COORDINATE_M,
    MAX_MESSAGE_BYTES,
    MAX_RESPONSE_BYTES,
)
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.skeleton import JOINT_COUNT, SKELETON_NAME, TrackingState
from skelfuse.protocol.transform import pose_from_position_yaw_pitch
from skelfuse.protocol.wire import (
    POSE_HINT_SOURCES,
    SENSOR_ID_PATTERN,
    SENSOR_TYPES,
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

REASONS = frozenset(
    {"too_large", "malformed", "version", "unknown_type", "bad_field", "bad_shape",
     "non_finite", "out_of_range"}
)  # fmt: skip
"""The reason tags of docs/protocol.md §5: the only ones ``decode`` may raise."""

_HEALTH = [HealthCheck.too_slow, HealthCheck.data_too_large]
settings.register_profile(
    "ci",
    parent=settings.get_profile("ci"),  # Hypothesis' own: derandomized, no database
    max_examples=2500,
    deadline=None,
    suppress_health_check=_HEALTH,
)
settings.register_profile(
    "wire-dev", max_examples=300, deadline=None, suppress_health_check=_HEALTH
)
if settings.get_current_profile_name() in {"default", "ci"}:  # --hypothesis-profile wins
    settings.load_profile("ci" if os.environ.get("CI") else "wire-dev")

UINT63 = 2**63 - 1
UINT64 = 2**64 - 1
TRACKED = int(TrackingState.TRACKED)
NOT_TRACKED = int(TrackingState.NOT_TRACKED)
F32Array = npt.NDArray[np.float32]


# --- valid messages -------------------------------------------------------------------------


_SEEN_SPECIALS = [MAX_COORDINATE_M, -MAX_COORDINATE_M, 0.0, -0.0, 1e-45, 49.999996, -3.5]
_UNSEEN_SPECIALS = [math.nan, 1e30, -3.4e38, 60.0, 0.0]


@st.composite
def bodies(draw: st.DrawFn, tracking_id: int) -> Body:
    """A body with joints within ±50 m, states 0..2, NaN or anything finite where NOT_TRACKED.

    Bulk values come from a seeded generator (drawing 75 floats one by one per body makes the
    suite ten times slower); hypothesis draws the seed, the state pattern and a few boundary
    values written over random joints, so edges and shrinking still work.
    """
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    pattern = draw(st.sampled_from(["tracked", "mixed", "none_tracked"]))
    if pattern == "tracked":
        states = np.full(JOINT_COUNT, TRACKED, dtype=np.uint8)
    elif pattern == "mixed":
        states = rng.integers(0, 3, JOINT_COUNT).astype(np.uint8)
    else:
        states = np.full(JOINT_COUNT, NOT_TRACKED, dtype=np.uint8)
    joints = rng.uniform(-MAX_COORDINATE_M, MAX_COORDINATE_M, (JOINT_COUNT, 3)).astype(np.float32)
    unseen = states == NOT_TRACKED
    joints[unseen] = np.where(rng.random((int(unseen.sum()), 3)) < 0.5, np.nan, 1e6)
    overrides = st.tuples(st.integers(0, JOINT_COUNT - 1), st.integers(0, 2), st.integers(0, 6))
    for joint, axis, k in draw(st.lists(overrides, max_size=4)):
        specials = _UNSEEN_SPECIALS if unseen[joint] else _SEEN_SPECIALS
        joints[joint, axis] = specials[k % len(specials)]
    return Body(tracking_id, joints, states)


@st.composite
def frames(draw: st.DrawFn) -> Frame:
    ids = draw(st.lists(st.integers(0, UINT64), max_size=MAX_BODIES, unique=True))
    floor = None
    if draw(st.booleans()):
        normal = np.array(draw(st.lists(st.floats(-1, 1), min_size=3, max_size=3)))
        if np.linalg.norm(normal) < 1e-3:
            normal = np.array([0.0, 1.0, 0.0])
        normal /= np.linalg.norm(normal)
        d = draw(st.floats(allow_nan=False, allow_infinity=False))
        floor = (float(normal[0]), float(normal[1]), float(normal[2]), d)
    return Frame(
        seq=draw(st.integers(0, UINT63)),
        t_capture_ns=draw(st.integers(0, UINT63)),
        bodies=tuple(draw(bodies(i)) for i in ids),
        floor=floor,
    )


@st.composite
def hellos(draw: st.DrawFn) -> Hello:
    pose = None
    source = None
    if draw(st.booleans()):
        coordinate = st.floats(-100, 100)
        pose = pose_from_position_yaw_pitch(
            (draw(coordinate), draw(coordinate), draw(coordinate)),
            draw(st.floats(-360, 360)),
            draw(st.floats(-90, 90)),
        )
        source = draw(st.sampled_from(sorted(POSE_HINT_SOURCES)))
    return Hello(
        sensor_id=draw(st.from_regex(SENSOR_ID_PATTERN, fullmatch=True)),
        sensor_type=draw(st.sampled_from(sorted(SENSOR_TYPES))),
        agent_version=draw(st.text(max_size=64)),
        fps=draw(st.floats(0, 240, exclude_min=True)),
        t_ns=draw(st.integers(0, UINT63)),
        skeleton=SKELETON_NAME,
        pose_hint=pose,
        pose_hint_source=source,
    )


# msgpack values that round-trip to themselves (lists not tuples, str keys, no NaN).
_scalars = (
    st.none()
    | st.booleans()
    | st.integers(-(2**63), UINT64)
    | st.floats(allow_nan=False)
    | st.text(max_size=40)
    | st.binary(max_size=40)
)
_values = st.recursive(
    _scalars,
    lambda inner: (
        st.lists(inner, max_size=8) | st.dictionaries(st.text(max_size=10), inner, max_size=8)
    ),
    max_leaves=20,
)

messages: st.SearchStrategy[Message] = st.one_of(
    frames(),
    hellos(),
    st.builds(Welcome, st.text(max_size=40), st.floats(allow_nan=False, allow_infinity=False),
              st.integers(0, UINT63)),
    st.builds(Heartbeat, st.integers(0, UINT63)),
    st.builds(Request, st.integers(0, UINT63), st.text(max_size=40),
              st.dictionaries(st.text(max_size=10), _values, max_size=8)),
    st.builds(Response, st.integers(0, UINT63), st.just(True), _values),
    st.builds(Response, st.integers(0, UINT63), st.just(False), st.none(), st.text(min_size=1)),
    st.builds(ErrorMessage, st.text(max_size=40), st.text(max_size=200)),
    st.just(Bye()),
)  # fmt: skip


def expected_after_decode(message: Message) -> Message:
    """What ``decode(encode(message))`` must return: NOT_TRACKED positions become NaN."""
    if not isinstance(message, Frame):
        return message
    normalised = []
    for body in message.bodies:
        joints: F32Array = body.joints_m.astype(np.float32)
        joints[body.states == NOT_TRACKED] = np.nan
        normalised.append(Body(body.tracking_id, joints, body.states))
    return Frame(message.seq, message.t_capture_ns, tuple(normalised), message.floor)


def assert_same(actual: Any, expected: Any, where: str = "message") -> None:
    """Deep equality; arrays compare exactly with NaN equal to NaN."""
    if isinstance(expected, np.ndarray):
        assert isinstance(actual, np.ndarray), where
        assert actual.dtype == expected.dtype and actual.shape == expected.shape, where
        np.testing.assert_array_equal(actual, expected, err_msg=where)
    elif hasattr(expected, "__dataclass_fields__"):
        assert type(actual) is type(expected), f"{where}: {type(actual).__name__}"
        for name, spec in expected.__dataclass_fields__.items():
            if spec.compare:  # Frame.stacked: the decoder's arrays, not part of the message
                assert_same(getattr(actual, name), getattr(expected, name), f"{where}.{name}")
    elif isinstance(expected, tuple | list):
        assert type(actual) is type(expected) and len(actual) == len(expected), where
        for i, (a, e) in enumerate(zip(actual, expected, strict=True)):
            assert_same(a, e, f"{where}[{i}]")
    elif isinstance(expected, dict):
        assert isinstance(actual, dict) and actual.keys() == expected.keys(), where
        for key in expected:
            assert_same(actual[key], expected[key], f"{where}[{key!r}]")
    elif isinstance(expected, float) and math.isnan(expected):
        assert isinstance(actual, float) and math.isnan(actual), where
    else:
        assert type(actual) is type(expected) and actual == expected, (
            f"{where}: {actual!r} != {expected!r}"
        )


def assert_valid(message: Message) -> None:
    """The invariants of a decoded message (docs/protocol.md §6), and a stable re-encode."""
    if isinstance(message, Frame):
        assert 0 <= message.seq <= UINT63 and 0 <= message.t_capture_ns <= UINT63
        assert len(message.bodies) <= MAX_BODIES
        assert len({b.tracking_id for b in message.bodies}) == len(message.bodies)
        for body in message.bodies:
            assert 0 <= body.tracking_id <= UINT64
            assert body.joints_m.shape == (JOINT_COUNT, 3) and body.joints_m.dtype == np.float32
            assert body.states.shape == (JOINT_COUNT,) and body.states.max() <= TRACKED
            seen = body.states != NOT_TRACKED
            assert np.isfinite(body.joints_m[seen]).all()
            assert (np.abs(body.joints_m[seen]) <= MAX_COORDINATE_M).all()
            assert np.isnan(body.joints_m[~seen]).all()
        if message.floor is not None:
            assert all(math.isfinite(x) for x in message.floor)
            assert abs(math.hypot(*message.floor[:3]) - 1.0) <= 1e-3
    elif isinstance(message, Hello):
        assert SENSOR_ID_PATTERN.fullmatch(message.sensor_id)
        assert message.sensor_type in SENSOR_TYPES and message.skeleton == SKELETON_NAME
        assert 0 < message.fps <= 240 and len(message.agent_version) <= 64
        if message.pose_hint is not None:
            assert message.pose_hint.shape == (4, 4) and np.isfinite(message.pose_hint).all()
            assert message.pose_hint_source in POSE_HINT_SOURCES
    elif isinstance(message, Welcome):
        assert math.isfinite(message.heartbeat_interval_s)
    again = decode(encode(message), MAX_RESPONSE_BYTES)
    if isinstance(message, Response) and not message.ok and message.error == "":
        # Known asymmetry: decode accepts error "", encode writes "unspecified error" instead.
        message = Response(message.request_id, False, None, "unspecified error")
    assert_same(again, message)


def assert_decodes_or_refuses(buf: bytes, max_bytes: int = MAX_MESSAGE_BYTES) -> None:
    """``decode`` either returns a valid message or raises DecodeError with a documented reason.

    Any other exception propagates and fails the test with its traceback.
    """
    try:
        message = decode(buf, max_bytes)
    except DecodeError as exc:
        reason = exc.reason
    else:
        event(f"decoded a valid {type(message).__name__}")
        assert_valid(message)
        return
    event(f"refused: {reason}")  # shown by pytest --hypothesis-show-statistics
    assert reason in REASONS, f"undocumented reason {reason!r}"


# --- (a) arbitrary bytes --------------------------------------------------------------------


@given(
    buf=st.binary(max_size=600)
    | st.binary(max_size=60).map(lambda b: b"\x82\xa1v\x01\xa4type" + b),  # {"v": 1, "type": …
    max_bytes=st.sampled_from([MAX_MESSAGE_BYTES, MAX_RESPONSE_BYTES]),
)
def test_arbitrary_bytes_only_raise_decode_error(buf: bytes, max_bytes: int) -> None:
    assert_decodes_or_refuses(buf, max_bytes)


# --- (b) round trip -------------------------------------------------------------------------


@given(message=messages)
def test_valid_messages_round_trip(message: Message) -> None:
    buf = encode(message)
    assert len(buf) <= MAX_MESSAGE_BYTES or isinstance(message, Response)
    decoded = decode(buf, MAX_RESPONSE_BYTES)
    assert_same(decoded, expected_after_decode(message))
    assert encode(decoded) == encode(expected_after_decode(message))  # deterministic bytes


@given(frame=frames())
def test_frames_round_trip_with_nan_in_not_tracked_joints(frame: Frame) -> None:
    decoded = decode(encode(frame))
    assert isinstance(decoded, Frame)
    assert_same(decoded, expected_after_decode(frame))
    assert_valid(decoded)


# --- (c) mutated valid messages ---------------------------------------------------------------


_MARKERS = [0xC0, 0xC2, 0xC3, 0xC4, 0xCA, 0xCB, 0xCF, 0xD3, 0xD9, 0xDC, 0xDE, 0x90, 0x80, 0xA0,
            0x7F, 0xFF]  # fmt: skip


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    buf = bytearray(encode(draw(messages)))
    for _ in range(draw(st.sampled_from([1, 1, 1, 2, 3, 4]))):
        kind = draw(
            st.sampled_from(["flip", "flip", "flip", "set", "truncate", "insert", "delete"])
        )
        at = draw(st.integers(0, max(len(buf) - 1, 0)))
        if kind == "flip" and buf:
            buf[at] ^= draw(st.integers(1, 255))
        elif kind == "set" and buf:  # msgpack markers that change a value's type or length
            buf[at] = draw(st.sampled_from(_MARKERS))
        elif kind == "truncate":
            del buf[at:]
        elif kind == "insert":
            buf[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif kind == "delete":
            del buf[at : at + draw(st.integers(1, 8))]
    return bytes(buf)


@given(buf=mutated())
def test_mutated_messages_decode_or_raise_decode_error(buf: bytes) -> None:
    assert_decodes_or_refuses(buf)


# --- (d) structure-aware garbage --------------------------------------------------------------

FIELDS: dict[str, list[str]] = {
    "frame": ["seq", "t_capture_ns", "bodies", "floor"],
    "hello": ["sensor_id", "sensor_type", "skeleton", "agent_version", "fps", "t_ns", "pose_hint"],
    "welcome": ["server_version", "heartbeat_interval_s", "t_ns"],
    "heartbeat": ["t_ns"],
    "request": ["id", "method", "params"],
    "response": ["id", "ok", "result", "error"],
    "error": ["code", "message"],
    "bye": [],
}

_odd_floats = st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 0.0, 1.0, 50.0, 50.000004,
                               1e308, -1e308, 5e-324, 240.0, 240.00001])  # fmt: skip
_odd_ints = st.sampled_from([0, 1, -1, 2, 3, 255, 256, 2**53 + 1, UINT63, UINT63 + 1, UINT64,
                             -(2**63)])  # fmt: skip
_junk_scalars = (
    st.none()
    | st.booleans()
    | _odd_ints
    | st.integers(-(2**63), UINT64)
    | _odd_floats
    | st.floats()
    | st.text(max_size=20)
    | st.sampled_from(["kinect-a", "sim", SKELETON_NAME, "manual", "sim_truth", "kinect-a\n", ""])
    | st.binary(max_size=40)
)


def mostly(
    good: st.SearchStrategy[Any], bad: st.SearchStrategy[Any], odds: int = 4
) -> st.SearchStrategy[Any]:
    """``good`` about ``odds`` times out of ``odds + 1``, else ``bad``.

    (``good | bad`` would weigh each of ``bad``'s own alternatives like ``good``; and hypothesis
    favours the ends of an integer range, so ``bad`` is chosen on 1, not on 0.)
    """
    return st.integers(0, odds).flatmap(lambda k: bad if k == 1 else good)


@st.composite
def joint_blobs(draw: st.DrawFn) -> bytes:
    """300 bytes of float32 joints within ±50 m, with a few specials (NaN, ±inf, > 50 m)."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    joints = rng.uniform(-MAX_COORDINATE_M, MAX_COORDINATE_M, JOINT_COUNT * 3).astype("<f4")
    specials = st.sampled_from([math.nan, math.inf, -math.inf, 50.0, -50.000004, 1e30, 0.0])
    for index, value in draw(st.lists(st.tuples(st.integers(0, 74), specials), max_size=2)):
        joints[index] = value
    return joints.tobytes()


@st.composite
def state_blobs(draw: st.DrawFn) -> bytes:
    """25 tracking states 0..2, sometimes with an out-of-range one."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    states = rng.integers(0, 3, JOINT_COUNT).astype(np.uint8)
    for index, value in draw(
        st.lists(st.tuples(st.integers(0, 24), st.integers(0, 255)), max_size=1)
    ):
        states[index] = value
    return states.tobytes()


@st.composite
def body_maps(draw: st.DrawFn) -> Any:
    body: dict[str, Any] = {
        "id": draw(mostly(st.integers(0, 5), _odd_ints | _junk_scalars)),
        "joints": draw(mostly(joint_blobs(), st.binary(max_size=310) | _junk_scalars)),
        "states": draw(mostly(state_blobs(), st.binary(max_size=30) | _junk_scalars)),
    }
    if draw(st.integers(0, 9)) == 0:
        del body[draw(st.sampled_from(sorted(body)))]
    return draw(mostly(st.just(body), _junk_scalars | st.lists(_junk_scalars, max_size=3)))


@st.composite
def pose_hints(draw: st.DrawFn) -> Any:
    rigid = pose_from_position_yaw_pitch((1.0, 2.0, 3.0), draw(st.floats(-180, 180)), 10.0)
    matrix: list[Any] = [float(x) for x in rigid.reshape(16)]
    for _ in range(draw(st.integers(0, 3))):
        matrix[draw(st.integers(0, 15))] = draw(_junk_scalars)
    matrix = draw(mostly(st.just(matrix), st.lists(st.floats() | _odd_ints, max_size=20)))
    hint: dict[str, Any] = {
        "T_world_from_sensor": matrix,
        "source": draw(mostly(st.sampled_from(sorted(POSE_HINT_SOURCES)), _junk_scalars)),
    }
    return draw(mostly(st.just(hint), _junk_scalars))


_unit_floor = st.tuples(st.floats(-1, 1), st.floats(0.1, 1), st.floats(-1, 1)).map(
    lambda n: [x / math.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2) for x in n]
)
_GOOD: dict[str, st.SearchStrategy[Any]] = {
    "seq": st.integers(0, UINT63),
    "t_capture_ns": st.integers(0, UINT63),
    "t_ns": st.integers(0, UINT63),
    "id": st.integers(0, UINT63),
    "bodies": st.lists(body_maps(), max_size=MAX_BODIES + 1),
    "floor": st.none() | st.tuples(_unit_floor, st.floats(-3, 3)).map(lambda x: [*x[0], x[1]]),
    "sensor_id": st.sampled_from(["kinect-a", "a", "A" * 64, "x.y_z-1"]),
    "sensor_type": st.sampled_from(sorted(SENSOR_TYPES)),
    "skeleton": st.just(SKELETON_NAME),
    "agent_version": st.text(max_size=80),
    "fps": st.floats(0, 300),
    "pose_hint": st.none() | pose_hints(),
    "server_version": st.text(max_size=20),
    "heartbeat_interval_s": st.floats(0, 60),
    "method": st.text(max_size=20),
    "params": st.dictionaries(st.text(max_size=10), _values, max_size=8),
    "ok": st.booleans(),
    "result": _values,
    "error": st.text(max_size=40),
    "code": st.sampled_from(["not_registered", "sensor_id_in_use", ""]),
    "message": st.text(max_size=40),
}


def _field_values(name: str) -> st.SearchStrategy[Any]:
    """Mostly a plausible value of the right type, else anything (wrong type, NaN, huge...)."""
    wrong: st.SearchStrategy[Any] = _junk_scalars
    if name == "floor":
        wrong = st.lists(mostly(st.floats(-1, 1), _junk_scalars), min_size=3, max_size=5) | wrong
    return mostly(_GOOD[name], wrong, 6)


@st.composite
def garbage_maps(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(sorted(FIELDS)))
    raw: dict[str, Any] = {
        "v": draw(mostly(st.just(1), _junk_scalars, 19)),
        "type": draw(mostly(st.just(kind), _junk_scalars, 19)),
    }
    for name in FIELDS[kind]:
        if draw(st.integers(0, 9)) > 0:  # mostly present
            raw[name] = draw(_field_values(name))
    for _ in range(draw(st.integers(0, 2))):  # extra keys are ignored, not refused
        raw[draw(st.text(max_size=8))] = draw(_junk_scalars)
    packed: bytes = msgpack.packb(raw, use_bin_type=True)
    return packed


@given(buf=garbage_maps())
def test_structured_garbage_raises_a_documented_reason(buf: bytes) -> None:
    assert_decodes_or_refuses(buf)
