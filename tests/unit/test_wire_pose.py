"""Moving sensors on the wire (docs/protocol.md §6.3, §6.1, §6.2): a frame's sensor pose,
``moving`` and ``pose_space`` in ``hello``, ``features`` in ``welcome``; golden bytes, both
decode paths, every rejection, and v1 peers that do not know the fields.

The golden file ``tests/data/frame_pose_v1.bin`` is the golden frame of test_wire.py with a
pose; regenerate it (only after a deliberate format change) with
``SKELFUSE_REGEN_GOLDEN=1 python -m pytest tests/unit/test_wire_pose.py``.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from typing import Any

import msgpack
import pytest
from hypothesis import given, strategies as st

from skelfuse.protocol import wire_canonical
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.wire import (
    Frame,
    Hello,
    SensorPose,
    Welcome,
    decode,
    decode_frame_precisely,
    encode,
)
from skelfuse.protocol.wire_bulk import frame_in_bulk
from skelfuse.protocol.wire_canonical import canonical_frame
from tests.unit.test_wire import (
    assert_same,
    golden_bytes,
    golden_frame,
    golden_hello,
    pack,
    raw_frame,
    raw_hello,
)
from tests.unit.test_wire_bulk import assert_identical
from tests.unit.test_wire_canonical import outcome, without_canonical
from tests.unit.test_wire_properties import frames

# Yaw about +Y by 2·atan(0.6/0.8) ≈ 73.7°, at head height: every number exact in binary but 0.6.
GOLDEN_POSE = SensorPose(position_m=(0.25, 1.625, -0.5), rotation_xyzw=(0.0, 0.6, 0.0, 0.8))


def pose_frame() -> Frame:
    return dataclasses.replace(golden_frame(), pose=GOLDEN_POSE)


def test_golden_frame_with_a_pose() -> None:
    fixed = pose_frame()
    golden = golden_bytes("frame_pose_v1.bin", encode(fixed))
    assert encode(fixed) == golden
    assert_same(decode(golden), fixed, "frame_pose_v1")
    # The only difference from frame_v1.bin: a 7th key "pose", 7 float64, and the map's size.
    plain = golden_bytes("frame_v1.bin", encode(golden_frame()))
    extra = b"\xa4pose\x97" + b"".join(struct.pack(">Bd", 0xCB, v) for v in _flat(GOLDEN_POSE))
    assert golden == b"\x87" + plain[1:] + extra
    assert plain[0] == 0x86


@pytest.mark.skipif(not wire_canonical.ENABLED, reason="msgspec is not installed")
def test_the_msgspec_path_reads_the_golden_pose() -> None:
    golden = golden_bytes("frame_pose_v1.bin", encode(pose_frame()))
    bulk = canonical_frame(golden)
    assert bulk is not None
    assert_same(bulk.pose, GOLDEN_POSE, "canonical pose")
    # and the precise path gives the same frame
    raw = msgpack.unpackb(golden, raw=False)
    assert_same(decode_frame_precisely(raw), pose_frame(), "precise")


def test_a_frame_without_a_pose_encodes_and_decodes_as_before() -> None:
    plain = encode(golden_frame())
    assert plain == golden_bytes("frame_v1.bin", plain)
    assert b"pose" not in plain
    decoded = decode(plain)
    assert isinstance(decoded, Frame) and decoded.pose is None
    if wire_canonical.ENABLED:
        bulk = canonical_frame(plain)
        assert bulk is not None and bulk.pose is None
    assert frame_in_bulk(msgpack.unpackb(plain, raw=False)) is not None  # the bulk path too


def test_an_old_server_ignores_the_pose() -> None:
    raw = msgpack.unpackb(encode(pose_frame()), raw=False)
    del raw["pose"]
    assert_same(decode(pack(raw)), golden_frame(), "without pose")


def test_nil_pose_is_no_pose() -> None:
    decoded = decode(pack(raw_frame(pose=None)))
    assert isinstance(decoded, Frame) and decoded.pose is None


def test_a_non_canonical_pose_takes_the_msgpack_paths_with_the_same_value() -> None:
    ints = raw_frame(pose=[0, 1, 0, 0, 0, 0, 1])  # integers: valid, not the reference bytes
    if wire_canonical.ENABLED:
        assert canonical_frame(pack(ints)) is None
    decoded = decode(pack(ints))
    assert isinstance(decoded, Frame)
    assert_same(decoded.pose, SensorPose((0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0)))


@pytest.mark.parametrize(
    ("pose", "reason"),
    [
        ([0.0, 1.0, 0.0, 0.0, 0.0, 0.0], "bad_shape"),
        ([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0], "bad_shape"),
        ({"position_m": [0.0, 0.0, 0.0]}, "bad_shape"),
        ([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, True], "bad_shape"),
        ([0.0, "1", 0.0, 0.0, 0.0, 0.0, 1.0], "bad_shape"),
        ([math.nan, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0], "non_finite"),
        ([0.0, 1.0, math.inf, 0.0, 0.0, 0.0, 1.0], "non_finite"),
        ([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, math.nan], "non_finite"),
        ([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], "out_of_range"),
        ([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.01], "out_of_range"),
        ([0.0, 1.0, 0.0, 0.5, 0.5, 0.5, 0.5 + 2e-3], "out_of_range"),
    ],
)
def test_bad_poses_are_refused_on_every_path(pose: Any, reason: str) -> None:
    buf = pack(raw_frame(pose=pose))
    if wire_canonical.ENABLED:
        assert canonical_frame(buf) is None
    assert frame_in_bulk(msgpack.unpackb(buf, raw=False)) is None
    with pytest.raises(DecodeError) as info:
        decode(buf)
    assert info.value.reason == reason


@pytest.mark.skipif(not wire_canonical.ENABLED, reason="msgspec is not installed")
def test_a_bad_pose_in_canonical_bytes_is_not_taken_by_the_msgspec_path() -> None:
    # The reference encoder's bytes, a quaternion off unit: msgspec parses it, the check refuses.
    bad = dataclasses.replace(golden_frame(), pose=SensorPose((0.0, 0.0, 0.0), (0, 0, 0, 0.9)))
    buf = encode(bad)
    assert canonical_frame(buf) is None
    with pytest.raises(DecodeError, match="unit"):
        decode(buf)


def test_hello_of_a_moving_sensor_round_trips() -> None:
    hello = dataclasses.replace(golden_hello(), moving=True, pose_space="quest-room_1")
    assert_same(decode(encode(hello)), hello, "moving hello")


def test_hello_of_a_fixed_sensor_encodes_as_before() -> None:
    buf = encode(golden_hello())
    assert buf == golden_bytes("hello_v1.bin", buf)
    assert b"moving" not in buf and b"pose_space" not in buf
    decoded = decode(buf)
    assert isinstance(decoded, Hello)
    assert decoded.moving is False and decoded.pose_space is None


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"moving": 1}, "bad_field"),
        ({"moving": "yes"}, "bad_field"),
        ({"moving": True}, "bad_field"),  # a moving sensor must name its space
        ({"moving": True, "pose_space": ""}, "bad_field"),
        ({"moving": True, "pose_space": "room\n"}, "bad_field"),
        ({"moving": True, "pose_space": "a" * 65}, "bad_field"),
        ({"moving": True, "pose_space": 3}, "bad_field"),
    ],
)
def test_bad_moving_fields_are_refused(changes: dict[str, Any], reason: str) -> None:
    with pytest.raises(DecodeError) as info:
        decode(pack(raw_hello(**changes)))
    assert info.value.reason == reason


def test_welcome_features() -> None:
    plain = Welcome(server_version="0.1.0", heartbeat_interval_s=1.0, t_ns=5)
    assert b"features" not in encode(plain)  # as before the field
    assert_same(decode(encode(plain)), plain)
    both = dataclasses.replace(plain, features=("moving_sensors", "something_newer"))
    assert_same(decode(encode(both)), both)  # names the agent does not know are kept
    raw = msgpack.unpackb(encode(both), raw=False)
    for bad in ("moving_sensors", [1], ["x" * 65], {"moving_sensors": True}):
        raw["features"] = bad
        with pytest.raises(DecodeError) as info:
            decode(pack(raw))
        assert info.value.reason == "bad_field"


@st.composite
def wire_poses(draw: st.DrawFn) -> list[Any]:
    """7 numbers as a frame's ``pose``: mostly near-unit quaternions (both sides of the
    tolerance), sometimes any float (NaN, infinities, huge), sometimes an int."""
    position = draw(st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3))
    quaternion = draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4))
    norm = math.sqrt(sum(q * q for q in quaternion))
    if norm > 1e-6:
        scale = draw(st.sampled_from([1.0, 1 + 9e-4, 1 - 9e-4, 1 + 1.1e-3, 1 - 1.1e-3]))
        quaternion = [q / norm * scale for q in quaternion]
    values: list[Any] = position + quaternion
    index = draw(st.integers(0, 6))
    values[index] = draw(
        st.one_of(st.just(values[index]), st.floats(), st.integers(-(2**63), 2**63 - 1))
    )
    return values


@given(frame=frames(), pose=wire_poses())
def test_any_pose_decodes_the_same_on_every_path(frame: Frame, pose: list[Any]) -> None:
    raw = msgpack.unpackb(encode(dataclasses.replace(frame, pose=None)), raw=False)
    buf = pack({**raw, "pose": pose})  # after floor: the reference encoder's order
    got, want = outcome(buf), without_canonical(buf)
    if isinstance(want, Frame):
        assert isinstance(got, Frame) and got.pose is not None
        assert_identical(got, want)
        if wire_canonical.ENABLED and all(type(x) is float for x in pose):
            assert canonical_frame(buf) is not None  # canonical bytes: the msgspec path took it
    else:
        assert got == want


def _flat(pose: SensorPose) -> tuple[float, ...]:
    return pose.position_m + pose.rotation_xyzw
