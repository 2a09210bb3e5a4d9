"""Requests to agents (server/agent_requests.py) through a real hub, without sockets: the hub
routes responses back, accepts a large one only while it is awaited, and gives a busy agent
longer before it counts as gone. Time is the hub's arguments; no test waits on the wall."""

from __future__ import annotations

import asyncio

import pytest

from skelfuse.protocol.wire import Hello, Message, Request, Response, decode, encode
from skelfuse.server.agent_requests import AgentRequests
from skelfuse.server.errors import AgentRequestFailed, SensorUnavailable
from skelfuse.server.hub import FusionHub
from skelfuse.server.settings import Settings


def connected_hub() -> tuple[FusionHub, AgentRequests, asyncio.Queue[Request]]:
    """A hub with sensor ``cam`` registered and the requests attached; the queue gets every
    request sent."""
    hub = FusionHub(Settings(heartbeat_interval_s=1.0))
    hub.handle_message(b"r", [encode(Hello("cam", "sim", "t", 30.0, 0))], 0.0, 0.0)
    sent: asyncio.Queue[Request] = asyncio.Queue()

    async def send(routing_id: bytes, message: Message) -> None:
        assert routing_id == b"r"
        assert isinstance(message, Request)
        sent.put_nowait(message)

    agents = AgentRequests(hub, send)
    hub.attach_requests(agents)
    return hub, agents, sent


async def test_a_request_gets_its_response_and_a_large_one_only_while_awaited() -> None:
    hub, agents, sent = connected_hub()
    task = asyncio.create_task(agents.request("cam", "depth_cloud", {"max_points": 5000}, 5.0))
    request = await sent.get()
    assert agents.awaiting("cam")
    big = encode(Response(request.request_id, ok=True, result={"points": b"\1" * 200_000}))
    hub.handle_message(b"r", [big], 0.0, 0.1)  # 200 KB: accepted because we are waiting
    assert len((await task)["points"]) == 200_000
    assert not agents.awaiting("cam")
    hub.handle_message(b"r", [big], 0.0, 0.2)  # nobody waits any more
    assert hub.sensors["cam"].frames_rejected["too_large"] == 1
    assert decode(encode(request)) == request


async def test_refusal_timeout_and_unknown_sensor_raise_server_errors() -> None:
    hub, agents, sent = connected_hub()
    task = asyncio.create_task(agents.request("cam", "nope", {}, 5.0))
    request = await sent.get()
    refusal = Response(request.request_id, ok=False, error="method 'nope' not supported")
    hub.handle_message(b"r", [encode(refusal)], 0.0, 0.3)
    with pytest.raises(AgentRequestFailed, match="not supported"):
        await task
    with pytest.raises(AgentRequestFailed, match="did not answer"):
        await agents.request("cam", "slow", {}, 0.0)  # a zero timeout expires at once
    with pytest.raises(SensorUnavailable, match="ghost"):
        await agents.request("ghost", "depth_cloud", {}, 1.0)
    assert AgentRequestFailed.status == 502 and SensorUnavailable.status == 409


async def test_responses_nobody_asked_for_are_rejected() -> None:
    hub, _, _ = connected_hub()
    stray = encode(Response(99, ok=True, result=None))
    hub.handle_message(b"r", [stray], 0.0, 0.1)
    assert hub.sensors["cam"].frames_rejected["unexpected_response"] == 1
    lone = FusionHub(Settings())  # no request machinery attached
    lone.handle_message(b"r", [encode(Hello("cam", "sim", "t", 30.0, 0))], 0.0, 0.0)
    lone.handle_message(b"r", [stray], 0.0, 0.1)
    assert lone.sensors["cam"].frames_rejected["unexpected_response"] == 1


async def test_an_agent_busy_answering_gets_longer_before_it_is_offline() -> None:
    hub, agents, sent = connected_hub()
    task = asyncio.create_task(agents.request("cam", "depth_cloud", {}, 30.0))
    await sent.get()
    assert [s.sensor_id for s in hub.check_liveness(5.0)] == ["cam"]  # 2.8 s limit, ×10
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert hub.check_liveness(5.0) == []  # no longer awaited: silent for 5 s is gone
