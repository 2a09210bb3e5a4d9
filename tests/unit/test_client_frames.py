"""skelfuse.client without a server: typed frames from the server's own messages, the feed URL,
backoff, and that importing it pulls in none of the server's libraries."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import msgpack
import numpy as np
import pytest

from bench.live.encode import sample_frame
from skelfuse.client import Backoff, feed_url
from skelfuse.client.connection import redact
from skelfuse.client.frames import decode, frame_from, skeleton_from
from skelfuse.protocol.feed import frame_json
from skelfuse.protocol.hands import HandConfidence, Hands, HandState
from skelfuse.protocol.skeleton import JointId, skeleton_definition
from skelfuse.server.broadcast import encode_message, persons_orientations


def test_a_frame_as_the_server_sends_it_in_both_formats() -> None:
    fused = sample_frame(3)
    hands = Hands(HandState.CLOSED, HandState.OPEN, HandConfidence.LOW, HandConfidence.HIGH)
    fused = dataclasses.replace(
        fused, persons=(dataclasses.replace(fused.persons[0], hands=hands), *fused.persons[1:])
    )
    message = frame_json(fused, False, 1_763_712_345.5, persons_orientations(fused.persons))
    for binary in (False, True):
        frame = frame_from(decode(encode_message(message, binary)), received=7.0)
        assert (frame.seq, frame.t, frame.t_sent, frame.received) == (
            1042, 1_763_712_345.123456, 1_763_712_345.5, 7.0)  # fmt: skip
        assert [p.id for p in frame.persons] == [1, 2, 3]
        person = frame.persons[0]
        assert person.joints.shape == (25, 3) and np.isnan(person.joints[15]).all()
        np.testing.assert_allclose(person.joints[JointId.HEAD], fused.persons[0].joints[3],
                                   atol=5e-5)  # fmt: skip
        assert person.confidence[15] == 0.0 and person.sources == fused.persons[0].sources
        assert person.hands is not None and person.hands.left.state == "closed"
        assert person.hands.right.confidence == "high" and frame.persons[1].hands is None
        assert person.rotations is not None and person.rotations.local.shape == (25, 4)
        assert frame.raw == () and frame.extra == {}


def test_the_skeleton_message_and_unknown_keys() -> None:
    skeleton = skeleton_from(decode(json.dumps(skeleton_definition())))
    assert skeleton.joints[3] == "Head" and skeleton.parents[0] == -1
    later = frame_from({"type": "frame", "v": 1, "seq": 1, "t": 2.0, "persons": [], "new": 1})
    assert later.t_sent is None and later.extra == {"new": 1}
    with pytest.raises(ValueError, match="skeleton message first"):
        skeleton_from({"type": "frame"})
    with pytest.raises(ValueError, match="not a feed message"):
        decode(msgpack.packb([1, 2]))
    with pytest.raises(ValueError, match="not a feed message"):
        decode("{")


def test_feed_url_takes_http_and_ws_addresses_and_the_options() -> None:
    assert feed_url("http://127.0.0.1:8000") == "ws://127.0.0.1:8000/ws/skeletons"
    assert feed_url("https://h", token="a b", rotations=True, raw=True, format="msgpack") == (
        "wss://h/ws/skeletons?format=msgpack&raw=1&rotations=1&token=a+b"
    )
    assert feed_url("ws://h:1/ws/skeletons?x=1") == "ws://h:1/ws/skeletons?x=1"
    assert feed_url("h:8000") == "ws://h:8000/ws/skeletons"
    assert redact("ws://h/ws/skeletons?raw=1&token=secret") == "ws://h/ws/skeletons?raw=1&token=***"
    with pytest.raises(ValueError, match="not an http"):
        feed_url("ftp://h")


def test_backoff_grows_to_its_limit_and_stops_after_its_attempts() -> None:
    delays = Backoff(first_s=0.5, factor=2.0, max_s=3.0, attempts=6).delays()
    assert list(delays) == [0.5, 1.0, 2.0, 3.0, 3.0]
    assert list(Backoff(attempts=1).delays()) == []


def test_the_client_imports_no_server_library() -> None:
    code = (
        "import sys, skelfuse.client; "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'fastapi', 'starlette', "
        "'uvicorn', 'scipy', 'open3d', 'orjson', 'prometheus_client', 'zmq'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
