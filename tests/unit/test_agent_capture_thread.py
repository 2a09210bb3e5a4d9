"""The agent reads its source in a thread of its own and answers the server's heartbeats while
the source waits for a frame (agent/capture_thread.py): the echo's stamp is the server's
measure of the agent's clock, and one answered a frame period late biased it by half that."""

from __future__ import annotations

import select
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import zmq

from skelfuse.agent.capture_thread import CaptureThread
from skelfuse.agent.runner import run_agent
from skelfuse.agent.sources.base import Capture
from skelfuse.protocol.wire import Body, Frame, Heartbeat, Hello, Welcome, decode, encode

pytestmark = pytest.mark.timeout(60)


def body() -> Body:
    return Body(1, np.zeros((25, 3), dtype=np.float32), np.full(25, 2, dtype=np.uint8))


class ScriptedSource:
    """Gives ``ready`` captures at once, then blocks in ``next_capture`` (ignoring its timeout,
    as a slow SDK call may) until ``release`` is set; ``fail`` makes the next read raise."""

    sensor_type = "kinect_v2"
    fps = 30.0

    def __init__(self, ready: int) -> None:
        self.ready = ready
        self.release = threading.Event()
        self.blocked = threading.Event()
        self.fail: Exception | None = None
        self.closed = False
        self._t_ns = time.time_ns()

    def pose_hint(self) -> None:
        return None

    def next_capture(self, timeout_s: float) -> Capture | None:
        if self.fail is not None:
            raise self.fail
        if self.ready > 0:
            self.ready -= 1
            self._t_ns += 33_000_000
            return Capture(self._t_ns, (body(),))
        self.blocked.set()
        self.release.wait(10.0)
        return None

    def close(self) -> None:
        self.closed = True


def wait_for(condition: Any, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.005)
    return False


def test_captures_come_out_in_order_and_wake_the_reader() -> None:
    source = ScriptedSource(ready=5)
    with CaptureThread(source) as thread:
        assert wait_for(source.blocked.is_set)
        readable, _, _ = select.select([thread.fileno()], [], [], 5.0)
        assert readable, "no wake byte for the captures"
        taken = thread.take()
        assert [c.t_capture_ns for c in taken] == sorted(c.t_capture_ns for c in taken)
        assert len(taken) == 5
        assert thread.take() == []
        source.release.set()


def test_an_error_from_the_source_reaches_the_reader() -> None:
    source = ScriptedSource(ready=0)
    source.fail = RuntimeError("device unplugged")
    with CaptureThread(source) as thread:
        assert wait_for(lambda: thread._error is not None)
        with pytest.raises(RuntimeError, match="device unplugged"):
            thread.take()


@contextmanager
def registered_agent(source: ScriptedSource) -> Iterator[tuple[zmq.Socket[Any], bytes]]:
    """The real agent loop streaming ``source`` to a ROUTER socket playing the server, which
    has welcomed it; yields (that socket, the agent's routing id); stops the agent after."""
    context: zmq.Context[Any] = zmq.Context()
    server = context.socket(zmq.ROUTER)
    server.linger = 0
    port = server.bind_to_random_port("tcp://127.0.0.1")
    stop = threading.Event()
    agent = threading.Thread(
        target=run_agent, args=("cam-a", source, f"tcp://127.0.0.1:{port}"), kwargs={"stop": stop}
    )
    agent.start()
    try:
        assert server.poll(5000), "no hello"
        routing_id, payload = server.recv_multipart()
        assert isinstance(decode(payload), Hello)
        server.send_multipart([routing_id, encode(Welcome("9.9", 1.0, 2, ()))])
        yield server, routing_id
    finally:
        source.release.set()
        stop.set()
        agent.join(10)
        server.close(linger=0)
        context.term()
    assert not agent.is_alive()
    assert source.closed


def test_a_heartbeat_is_echoed_while_the_source_waits_for_a_frame() -> None:
    source = ScriptedSource(ready=3)
    with registered_agent(source) as (server, routing_id):
        # The source hands over its frames, then blocks as if waiting for the next one.
        assert wait_for(source.blocked.is_set), "the source was never read"
        time.sleep(0.2)  # the agent's loop is now waiting; before the fix it sat in the source
        stamp = 123_456_789
        server.send_multipart([routing_id, encode(Heartbeat(t_ns=stamp))])
        echoed = False
        end = time.monotonic() + 5.0
        while not echoed and time.monotonic() < end and server.poll(100):
            _, payload = server.recv_multipart()
            message = decode(payload)
            echoed = isinstance(message, Heartbeat) and message.echo_ns == stamp
        assert echoed, "no echo while the source was waiting for a frame"
        assert not source.release.is_set() and source.blocked.is_set()


def test_frames_still_go_out_in_order_with_their_seq() -> None:
    source = ScriptedSource(ready=0)
    with registered_agent(source) as (server, _):
        assert wait_for(source.blocked.is_set)
        time.sleep(0.2)  # registered by now
        source.ready = 4
        source.release.set()  # the blocked read returns; the next four give frames
        frames: list[Frame] = []
        end = time.monotonic() + 5.0
        while len(frames) < 4 and time.monotonic() < end and server.poll(100):
            _, payload = server.recv_multipart()
            if isinstance(message := decode(payload), Frame):
                frames.append(message)
        assert [f.seq for f in frames] == [1, 2, 3, 4]
        stamps = [f.t_capture_ns for f in frames]
        assert stamps == sorted(stamps)
