"""The agent's handshake watch (agent/handshake.py) with an injected clock: no welcome for 10 s
and no handshake report says so once, then not again for 30 s; a welcome resets the count."""

from __future__ import annotations

import logging

import pytest
import zmq

from skelfuse.agent.handshake import NO_WELCOME_S, REPEAT_S, HandshakeWatch
from tests.support import free_port


def test_no_welcome_is_said_once_per_repeat_time(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, logger="skelfuse.agent.handshake")
    now = [0.0]
    context = zmq.Context()
    socket = context.socket(zmq.DEALER)
    socket.linger = 0
    endpoint = f"tcp://127.0.0.1:{free_port()}"  # nobody listens
    socket.connect(endpoint)
    watch = HandshakeWatch(socket, endpoint, has_keys=False, clock=lambda: now[0])
    try:
        watch.poll(registered=False)
        now[0] = NO_WELCOME_S - 0.1
        watch.poll(registered=False)
        assert not caplog.records
        now[0] = NO_WELCOME_S
        watch.poll(registered=False)
        now[0] = NO_WELCOME_S + REPEAT_S - 1
        watch.poll(registered=False)
        assert len(caplog.records) == 1
        assert "no welcome from" in caplog.records[0].getMessage()
        assert "--curve" in caplog.records[0].getMessage()
        now[0] += 1
        watch.poll(registered=True)  # registered: the wait starts over
        now[0] += NO_WELCOME_S - 1
        watch.poll(registered=False)
        assert len(caplog.records) == 1
        assert watch.failures == {}
    finally:
        watch.close()
        socket.close(linger=0)
        context.term()
