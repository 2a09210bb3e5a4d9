"""Answers to the server's requests over real ZeroMQ sockets (docs/protocol.md §4): a 4 MiB answer
the server waits for is accepted; a message over 1 MiB nobody asked for is refused and counted,
and the connection stays; an answer over the limit fails the request with the reason at once,
not with a time-out.

The server side is the real ROUTER socket, ingest loop, hub and request machinery in the test's
event loop; the agent side is the real :class:`AgentLink` in a thread.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
import zmq
import zmq.asyncio

from skelfuse.agent.link import AgentLink
from skelfuse.protocol.constants import MAX_RESPONSE_BYTES
from skelfuse.protocol.wire import Hello, Response, encode
from skelfuse.server.agent_requests import AgentRequests
from skelfuse.server.errors import AgentRequestFailed
from skelfuse.server.hub import FusionHub
from skelfuse.server.ingest import ingest_loop, liveness_loop, open_router, send_to
from skelfuse.server.settings import Settings
from tests.support import free_port

pytestmark = pytest.mark.timeout(60)


@dataclass
class Server:
    endpoint: str
    hub: FusionHub
    requests: AgentRequests


@pytest.fixture
async def server() -> AsyncIterator[Server]:
    context = zmq.asyncio.Context()
    endpoint = f"tcp://127.0.0.1:{free_port()}"
    socket = open_router(context, endpoint)
    hub = FusionHub(Settings())
    requests = AgentRequests(hub, lambda rid, message: send_to(socket, rid, message))
    hub.attach_requests(requests)
    tasks = [
        asyncio.create_task(ingest_loop(socket, hub, False)),
        asyncio.create_task(liveness_loop(socket, hub, 1.0)),
    ]
    yield Server(endpoint, hub, requests)
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    socket.close(linger=0)
    context.term()


def blob(params: dict[str, Any]) -> bytes:
    """The agent's handler: ``n`` bytes of answer."""
    return b"\x01" * int(params["n"])


@pytest.fixture
def agent(server: Server) -> Iterator[AgentLink]:
    """A real agent link for sensor ``cam`` answering ``blob`` requests, polled in a thread."""
    hello = lambda: Hello("cam", "sim", "test", 30.0, time.time_ns())  # noqa: E731
    link = AgentLink(server.endpoint, hello, handlers={"blob": blob})
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            link.poll(0.02)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    yield link
    stop.set()
    thread.join(timeout=10)
    link.close()


async def registered(server: Server, link: AgentLink) -> None:
    for _ in range(200):
        sensor = server.hub.sensors.get("cam")
        if link.registered and sensor is not None and sensor.connected:
            return
        await asyncio.sleep(0.05)
    raise AssertionError("the agent did not register")


def answer_payload_bytes(total: int) -> int:
    """The blob size whose encoded response is exactly ``total`` bytes."""
    overhead = len(encode(Response(1, ok=True, result=b""))) + 4  # bin32 header, larger id
    return total - overhead


async def test_a_4_mib_answer_is_accepted(server: Server, agent: AgentLink) -> None:
    await registered(server, agent)
    n = answer_payload_bytes(MAX_RESPONSE_BYTES)
    result = await server.requests.request("cam", "blob", {"n": n}, timeout_s=20)
    assert len(result) == n
    assert len(encode(Response(1, ok=True, result=result))) <= MAX_RESPONSE_BYTES
    assert server.hub.sensors["cam"].connected and not server.hub.sensors["cam"].frames_rejected


async def test_an_answer_over_the_limit_fails_the_request_with_the_reason(
    server: Server, agent: AgentLink
) -> None:
    await registered(server, agent)
    started = time.monotonic()
    # The agent itself refuses to send it and says why.
    with pytest.raises(AgentRequestFailed, match="over the protocol's limit"):
        await server.requests.request("cam", "blob", {"n": MAX_RESPONSE_BYTES + 1}, 20)
    assert time.monotonic() - started < 10


async def test_unrequested_1_mib_is_refused_and_a_too_large_answer_named(server: Server) -> None:
    """An agent that sends too large messages anyway (not this project's agent): an unrequested
    1.2 MB message is refused and counted, and its connection stays; a 4 MiB + 10 B answer fails
    the request at once with the reason, not with "did not answer within 20 s"."""
    dealer = zmq.asyncio.Context.instance().socket(zmq.DEALER)
    dealer.linger = 0
    dealer.connect(server.endpoint)
    try:
        await dealer.send(encode(Hello("cam", "sim", "test", 30.0, time.time_ns())))
        assert await dealer.poll(5000)
        await dealer.recv()  # welcome
        routing_id = server.hub.sensors["cam"].routing_id
        await dealer.send(encode(Response(99, ok=True, result=b"\x02" * 1_200_000)))
        for _ in range(100):
            if server.hub.sensors["cam"].frames_rejected["too_large"]:
                break
            await asyncio.sleep(0.05)
        assert server.hub.sensors["cam"].frames_rejected["too_large"] == 1
        task = asyncio.create_task(server.requests.request("cam", "blob", {}, 20))
        assert await dealer.poll(5000), "the connection was dropped"
        await dealer.recv()  # the request (id 1), on the same connection
        assert server.hub.sensors["cam"].routing_id == routing_id
        too_big = encode(Response(1, ok=True, result=b"\x03" * (MAX_RESPONSE_BYTES + 10)))
        started = time.monotonic()
        await dealer.send(too_big)
        with pytest.raises(AgentRequestFailed, match="was refused") as refused:
            await task
        assert time.monotonic() - started < 5
        assert "did not answer" not in str(refused.value)
        assert server.hub.sensors["cam"].frames_rejected["too_large"] == 2
        assert server.hub.sensors["cam"].connected
    finally:
        dealer.close(linger=0)
