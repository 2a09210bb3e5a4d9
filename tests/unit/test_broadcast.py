"""WebSocket fan-out (server/broadcast.py) with a fake socket and the time passed in: a
one-frame mailbox per client where the newest frame wins, a sender that takes the newest only
once its send is done, stalled clients disconnected, one encoding per (format, raw) variant.
No test waits on the wall clock."""

from __future__ import annotations

import asyncio
import json

import msgpack
import numpy as np
import pytest
from starlette.websockets import WebSocketDisconnect

from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.views import FusedPerson, View
from skelfuse.protocol.skeleton import JOINT_COUNT
from skelfuse.server.broadcast import (
    Broadcaster,
    Client,
    Outgoing,
    Variant,
    encode_message,
    outgoing,
    pump,
)

JSON, JSON_RAW, MSGPACK = Variant(False, False), Variant(False, True), Variant(True, False)


def fused_frame(seq: int = 7) -> FusedFrame:
    joints = np.zeros((JOINT_COUNT, 3)) + [0.0, 1.0, 2.0]
    joints[3] = np.nan
    view = View("cam", 2**63 + 5, joints, np.full(JOINT_COUNT, 2, np.uint8))
    person = FusedPerson(1, joints, np.full(JOINT_COUNT, 0.8), ("cam",), (view,))
    return FusedFrame(seq, 1000.25, 1000.3, (person,), (view,))


class FakeSocket:
    """Records what is sent; ``block_after`` sends complete, later ones never do."""

    def __init__(self, block_after: int | None = None, refuse: bool = False) -> None:
        self.sent: list[bytes | str] = []
        self.closes: list[tuple[int, str]] = []
        self.disconnected = asyncio.Event()
        self.block_after = block_after
        self.refuse = refuse
        self.delivered = asyncio.Event()

    async def send(self, message: Outgoing) -> None:
        payload = message.payload
        if self.refuse:
            raise WebSocketDisconnect(1001)
        if self.block_after is not None and len(self.sent) >= self.block_after:
            await asyncio.Event().wait()  # a client that reads nothing: the send never ends
        self.sent.append(payload)
        self.delivered.set()

    async def closed(self) -> None:
        await self.disconnected.wait()

    async def close(self, code: int, reason: str) -> None:
        self.closes.append((code, reason))


def payload_of(message: Outgoing | None) -> bytes | str | None:
    return None if message is None else message.payload


def test_a_message_is_framed_once_as_the_websocket_message_every_client_gets() -> None:
    assert outgoing("hi").framed == b"\x81\x02hi"  # FIN + text, unmasked, 2 bytes
    big = outgoing(b"x" * 300)
    assert big.framed[:4] == b"\x82\x7e\x01\x2c" and big.framed[4:] == big.payload


def test_the_mailbox_keeps_only_the_newest_frame_and_counts_the_rest() -> None:
    client = Broadcaster().add(JSON, "a", 0.0)
    for payload in ("f1", "f2", "f3", "f4"):
        client.offer(outgoing(payload), 0.0)
    assert payload_of(client.take()) == "f4" and client.take() is None
    assert client.conflated == 3 and not client.stalled.is_set()


def test_a_frame_waiting_longer_than_the_limit_marks_the_client_stalled() -> None:
    client = Broadcaster(send_timeout_s=5.0).add(JSON, "a", 0.0)
    client.offer(outgoing("f0"), 10.0)  # waiting from t = 10
    client.offer(outgoing("f1"), 15.0)  # 5 s: at the limit, not past it
    assert not client.stalled.is_set() and client.waiting_since == 10.0
    client.offer(outgoing("f2"), 15.1)
    assert client.stalled.is_set()


def test_a_client_that_takes_a_frame_restarts_the_stall_clock() -> None:
    client = Broadcaster(send_timeout_s=5.0).add(JSON, "a", 0.0)
    for step in range(240):  # 8 s of a 30 Hz feed; a slow reader takes 5 frames/s
        client.offer(outgoing(f"f{step}"), 10.0 + step / 30)
        if step % 6 == 5:
            assert payload_of(client.take()) == f"f{step}"  # always the newest
    assert not client.stalled.is_set() and client.conflated == 200


class DrainingSocket:
    """A socket whose sends end only when the test lets one drain (as the feed protocol's do)."""

    def __init__(self) -> None:
        self.sent: list[bytes | str] = []
        self.drained = asyncio.Semaphore(0)
        self.writing = asyncio.Event()

    async def send(self, message: Outgoing) -> None:
        self.sent.append(message.payload)
        self.writing.set()
        await self.drained.acquire()


async def test_the_sender_takes_the_newest_frame_once_the_previous_send_has_drained() -> None:
    client = Broadcaster().add(JSON, "a", 0.0)
    socket = DrainingSocket()
    task = asyncio.create_task(pump(client, socket.send, 5.0))
    client.offer(outgoing("f1"), 0.0)
    await socket.writing.wait()
    for payload in ("f2", "f3", "f4"):  # published while f1 is still draining
        client.offer(outgoing(payload), 0.0)
    socket.writing.clear()
    socket.drained.release()
    await socket.writing.wait()
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert socket.sent == ["f1", "f4"] and client.conflated == 2 and client.sent == 1


async def test_a_client_that_keeps_up_gets_every_frame() -> None:
    client = Broadcaster().add(JSON, "a", 0.0)
    socket = FakeSocket()
    task = asyncio.create_task(pump(client, socket.send, 5.0))
    for step in range(30):
        client.offer(outgoing(f"f{step}"), step / 30)
        await asyncio.sleep(0)  # the sender runs between two fusion steps
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert socket.sent == [f"f{step}" for step in range(30)] and client.conflated == 0


async def test_pump_gives_up_on_a_greeting_that_takes_too_long() -> None:
    client = Broadcaster().add(JSON, "a", 0.0)
    with pytest.raises(TimeoutError):  # zero timeout: at once
        await pump(client, FakeSocket(block_after=0).send, 0.0, outgoing("hello"))


def test_publish_encodes_once_per_variant_with_the_given_send_time() -> None:
    broadcaster = Broadcaster()
    clients = [broadcaster.add(v, str(i), 0.0) for i, v in enumerate([JSON, JSON, JSON_RAW])]
    binary = broadcaster.add(MSGPACK, "m", 0.0)
    broadcaster.publish(fused_frame(), 1000.5, 3.0)
    first, second, raw = (c.take() for c in clients)
    assert first is not None and raw is not None
    assert first is second, "one encoding, one framing, shared by the clients of a variant"
    message = json.loads(first.payload)
    assert message["t_sent"] == 1000.5 and message["seq"] == 7 and "raw" not in message
    assert message["persons"][0]["joints"][3] is None
    assert json.loads(raw.payload)["raw"][0]["tracking_id"] == str(2**63 + 5)
    assert msgpack.unpackb(payload_of(binary.take())) == message
    assert broadcaster.published == 1


def test_encode_message_never_sends_nan_in_json() -> None:
    """Browsers reject a bare NaN: JSON has null for it, as JSON.stringify writes it."""
    assert msgpack.unpackb(encode_message({"a": 1}, binary=True)) == {"a": 1}
    text = encode_message({"a": float("nan"), "b": [float("inf"), 0.5]}, binary=False)
    assert text == '{"a":null,"b":[null,0.5]}'


async def test_serve_greets_then_streams_until_the_client_leaves() -> None:
    broadcaster = Broadcaster()
    client = broadcaster.add(JSON, "a", 0.0)
    socket = FakeSocket()
    serving = asyncio.create_task(broadcaster.serve(client, socket, "hello"))
    client.offer(outgoing("f1"), 0.0)
    await socket.delivered.wait()
    while len(socket.sent) < 2:
        socket.delivered.clear()
        await socket.delivered.wait()
    socket.disconnected.set()
    await serving
    assert socket.sent == ["hello", "f1"]
    assert broadcaster.clients == {} and broadcaster.evicted == 0 and socket.closes == []


async def test_serve_disconnects_a_stalled_client_and_counts_it() -> None:
    broadcaster = Broadcaster(send_timeout_s=5.0)
    client: Client = broadcaster.add(MSGPACK, "slow", 0.0)
    socket = FakeSocket(block_after=1)  # takes the greeting, then reads nothing
    serving = asyncio.create_task(broadcaster.serve(client, socket, b"hello"))
    await socket.delivered.wait()
    for step in range(10):  # 30 Hz for a third of a second, then 6 s later
        broadcaster.publish(fused_frame(step), 1000.0 + step / 30, step / 30)
        await asyncio.sleep(0)
    assert not client.stalled.is_set()
    broadcaster.publish(fused_frame(11), 1006.5, 6.5)
    await serving
    assert socket.closes == [(1008, "client too slow")]
    assert broadcaster.evicted == 1 and broadcaster.clients == {}
    assert client.conflated >= 9


async def test_serve_forgets_a_client_that_is_gone_before_the_greeting() -> None:
    broadcaster = Broadcaster()
    client = broadcaster.add(JSON, "gone", 0.0)
    await broadcaster.serve(client, FakeSocket(refuse=True), "hello")
    assert broadcaster.clients == {} and broadcaster.evicted == 0
