"""The bulk path's joint checks on the bytes (``protocol.wire_bulk._joints_valid``), case by case.

test_wire_bulk.py holds the bulk and precise paths together on generated frames; these cases
pin each branch of the byte-level checks: what must still take the bulk path (with the precise
path's values, NaN payloads included) and what must be left to the precise checks.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np
import pytest

from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.protocol.wire import decode_frame_precisely
from skelfuse.protocol.wire_bulk import frame_in_bulk

NAN, INF = float("nan"), float("inf")


def frame(
    edits: list[tuple[int, int, int, float]], unseen: list[tuple[int, int]]
) -> dict[str, Any]:
    """Two bodies 2-3 m away, all TRACKED but ``unseen`` (body, joint); ``edits`` (body, joint,
    axis, value) set single coordinates; NOT_TRACKED joints are sent as NaN unless edited."""
    rng = np.random.default_rng(5)
    bodies = []
    for b in range(2):
        joints = rng.uniform(-2.0, 3.0, (JOINT_COUNT, 3)).astype("<f4")
        states = np.full(JOINT_COUNT, 2, dtype=np.uint8)
        for body, joint in unseen:
            if body == b:
                states[joint] = 0
                joints[joint] = NAN
        for body, joint, axis, value in edits:
            if body == b:
                joints[joint, axis] = value
        bodies.append({"id": 10 + b, "joints": joints.tobytes(), "states": states.tobytes()})
    raw = {"type": "frame", "seq": 1, "t_capture_ns": 5, "bodies": bodies, "floor": None}
    unpacked: dict[str, Any] = msgpack.unpackb(msgpack.packb(raw), raw=False)
    return unpacked


ACCEPTED = {
    "all small": ([], []),
    "NaN joints NOT_TRACKED": ([], [(0, 21), (1, 23), (1, 24)]),
    "a finite far value at a NOT_TRACKED joint": ([(0, 21, 1, 1000.0)], [(0, 21)]),
    "a NOT_TRACKED joint with one NaN coordinate": ([(0, 3, 0, 0.5), (0, 3, 2, 1.0)], [(0, 3)]),
    "a negative NaN at a NOT_TRACKED joint": ([(1, 4, 2, -NAN)], [(1, 4)]),
    "40 m at a tracked joint": ([(1, 7, 2, 40.0)], [(0, 21)]),
    "exactly -50 m at a tracked joint, nothing unseen": ([(0, 0, 0, -50.0)], []),
}
REFUSED = {
    "NaN at a tracked joint": ([(0, 2, 1, NAN)], [(0, 21)], "non_finite"),
    "inf at a NOT_TRACKED joint": ([(1, 21, 0, INF)], [(1, 21)], "non_finite"),
    "-inf at a tracked joint": ([(0, 9, 2, -INF)], [], "non_finite"),
    "just over 50 m at a tracked joint": ([(0, 5, 0, 50.000004)], [(1, 3)], "out_of_range"),
}


@pytest.mark.parametrize("case", sorted(ACCEPTED))
def test_valid_joints_take_the_bulk_path_with_the_precise_values(case: str) -> None:
    raw = frame(*ACCEPTED[case])
    bulk = frame_in_bulk(raw)
    assert bulk is not None
    precise = decode_frame_precisely(raw)
    for got, want in zip(bulk.joints_m, (b.joints_m for b in precise.bodies), strict=True):
        assert got.tobytes() == want.tobytes()  # NaN payloads too
        assert got.flags.writeable
    for got_states, body in zip(bulk.states, precise.bodies, strict=True):
        assert got_states.tobytes() == body.states.tobytes()


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_invalid_joints_are_left_to_the_precise_checks(case: str) -> None:
    edits, unseen, reason = REFUSED[case]
    raw = frame(edits, unseen)
    assert frame_in_bulk(raw) is None
    with pytest.raises(DecodeError) as caught:
        decode_frame_precisely(raw)
    assert caught.value.reason == reason
