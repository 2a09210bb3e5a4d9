"""The depth-cloud codec (protocol/depth_cloud.py) against bytes written without it, and the SDK
sources' shared reply (agent/sources/depth_reply.py)."""

from __future__ import annotations

import struct

import msgpack
import numpy as np
import pytest

from skelfuse.agent.sources.depth_reply import cloud_reply
from skelfuse.protocol.depth_cloud import (
    MAX_POINTS,
    MIN_POINTS,
    CloudRequest,
    decode_reply,
    decode_request,
    encode_reply,
    encode_request,
)
from skelfuse.protocol.errors import DecodeError

GOLDEN_POINTS = b"".join(
    struct.pack("<3f", *p) for p in [(1.0, 2.0, 3.0), (-0.5, 0.0, 4.25), (0.125, -1.5, 0.75)]
)
"""Three points as docs/protocol.md §6.5 lays them out: x, y, z little-endian float32 each."""


def test_encode_reply_writes_the_documented_layout() -> None:
    reply = encode_reply([[1.0, 2.0, 3.0], [-0.5, 0.0, 4.25], [0.125, -1.5, 0.75]], t_ns=7)
    assert reply == {
        "frame": "sensor",
        "units": "m",
        "count": 3,
        "points": GOLDEN_POINTS,
        "t_ns": 7,
    }


def test_decode_reply_reads_a_cloud_packed_by_hand() -> None:
    rows = [(0.01 * i, -0.02 * i, 1.0 + 0.001 * i) for i in range(MIN_POINTS)]
    raw = b"".join(struct.pack("<3f", *row) for row in rows) + struct.pack("<3f", np.nan, 0, 1)
    wire = msgpack.packb({"points": raw, "count": len(rows) + 1, "frame": "sensor"})
    points = decode_reply(msgpack.unpackb(wire))
    assert points.dtype == np.float64 and points.shape == (MIN_POINTS, 3)  # the NaN row is gone
    np.testing.assert_allclose(points, np.array(rows, dtype=np.float32))


@pytest.mark.parametrize(
    ("result", "reason", "message"),
    [
        ("not a map", "bad_field", "no 'points' bin"),
        ({"count": 3}, "bad_field", "no 'points' bin"),
        ({"points": GOLDEN_POINTS[:-1]}, "bad_shape", "not N × 3"),
        ({"points": GOLDEN_POINTS}, "out_of_range", "only 3 finite points"),
    ],
)
def test_decode_reply_refuses_bad_clouds_saying_why(
    result: object, reason: str, message: str
) -> None:
    with pytest.raises(DecodeError, match=message) as info:
        decode_reply(result)
    assert info.value.reason == reason


def test_request_params_round_trip_with_defaults_and_a_cap() -> None:
    assert encode_request(5000) == {"max_points": 5000}
    assert decode_request(encode_request(5000)) == CloudRequest(5000, 5.0)
    assert decode_request({}) == CloudRequest()
    assert decode_request({"max_points": 10**9, "max_range_m": 3}) == CloudRequest(MAX_POINTS, 3.0)
    for bad in ({"max_points": "many"}, {"max_points": 0}, {"max_points": True},
                {"max_range_m": float("nan")}, {"max_range_m": -1.0}):  # fmt: skip
        with pytest.raises(DecodeError):
            decode_request(bad)


def test_cloud_reply_drops_missing_depth_and_far_points_then_subsamples() -> None:
    points = np.array(
        [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [np.nan, 0.0, 1.0], [0.0, 0.0, 9.0], [0.1, 0, 2.0]]
    )
    reply = cloud_reply(points, {"max_range_m": 5.0}, device_timestamp_us=3)
    assert reply["count"] == 2 and reply["device_timestamp_us"] == 3
    assert reply["points"] == struct.pack("<6f", 0.0, 0.0, 1.0, 0.1, 0.0, 2.0)
    many = np.column_stack([np.zeros(1000), np.zeros(1000), np.linspace(0.5, 4.0, 1000)])
    assert cloud_reply(many, {"max_points": 250})["count"] == 250  # every 4th point
