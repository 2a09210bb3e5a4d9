"""A moving sensor's agent streams only to a server that announces ``moving_sensors``
(docs/protocol.md §6.1, §6.2): the real :class:`AgentLink` against a ROUTER socket playing the
server, and the real hub's ``welcome``.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator
from typing import Any

import pytest
import zmq

from skelfuse.agent.link import AgentLink
from skelfuse.protocol.constants import MOVING_SENSORS
from skelfuse.protocol.wire import Frame, Hello, SensorPose, Welcome, decode, encode
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings

ENDPOINT = "inproc://moving-server"
POSE = SensorPose((0.0, 1.6, 0.0), (0.0, 0.0, 0.0, 1.0))


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def router() -> Iterator[tuple[zmq.Context[Any], zmq.Socket[Any]]]:
    context: zmq.Context[Any] = zmq.Context()
    socket = context.socket(zmq.ROUTER)
    socket.linger = 0
    socket.bind(ENDPOINT)
    yield context, socket
    socket.close(linger=0)
    context.term()


def hello(moving: bool) -> Hello:
    base = Hello("head-a", "azure_kinect", "test", 30.0, 1)
    return dataclasses.replace(base, moving=True, pose_space="room") if moving else base


def register(
    router: tuple[zmq.Context[Any], zmq.Socket[Any]], moving: bool, features: tuple[str, ...]
) -> tuple[AgentLink, zmq.Socket[Any], bytes]:
    """An agent link registered with a ``welcome`` announcing ``features``."""
    context, server = router
    link = AgentLink(ENDPOINT, lambda: hello(moving), context=context, clock=FakeClock())
    link.poll()  # sends hello
    assert server.poll(2000)
    routing_id, payload = server.recv_multipart()
    assert isinstance(decode(payload), Hello)
    server.send_multipart([routing_id, encode(Welcome("9.9", 1.0, 2, features))])
    link.poll(2.0)
    assert link.registered
    return link, server, routing_id


def frame(seq: int) -> Frame:
    return Frame(seq, 10 + seq, (), (0.0, 1.0, 0.0, 0.8), POSE)


def test_a_moving_sensor_sends_no_frame_to_a_server_without_the_feature(
    router: tuple[zmq.Context[Any], zmq.Socket[Any]], caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.ERROR):
        link, server, _ = register(router, moving=True, features=())
    try:
        assert link.refusal is not None and MOVING_SENSORS in link.refusal
        assert any("configured as moving" in r.getMessage() for r in caplog.records)
        assert not link.send_frame(frame(1)) and not link.send_frame(frame(2))
        assert link.stats.frames_refused == 2 and link.stats.frames_sent == 0
        assert not server.poll(100)  # nothing reached the server
    finally:
        link.close()


def test_a_moving_sensor_streams_to_a_server_with_the_feature(
    router: tuple[zmq.Context[Any], zmq.Socket[Any]],
) -> None:
    link, server, _ = register(router, moving=True, features=(MOVING_SENSORS, "later"))
    try:
        assert link.refusal is None
        assert link.send_frame(frame(1))
        assert server.poll(2000)
        received = decode(server.recv_multipart()[1])
        assert isinstance(received, Frame) and received.pose == POSE
    finally:
        link.close()


def test_a_fixed_sensor_streams_to_any_server(
    router: tuple[zmq.Context[Any], zmq.Socket[Any]],
) -> None:
    link, server, _ = register(router, moving=False, features=())
    try:
        assert link.refusal is None
        assert link.send_frame(Frame(1, 11, ()))
        assert server.poll(2000)
    finally:
        link.close()


def test_the_server_announces_moving_sensors() -> None:
    # It poses moving sensors' frames (issue 15, item 2): a moving agent streams to it.
    hub = FusionHub(Settings())
    replies = hub.handle_message(b"r1", [encode(hello(moving=True))], 1.0, 1.0)
    welcome = replies[0]
    assert isinstance(welcome, Welcome)
    assert MOVING_SENSORS in welcome.features
