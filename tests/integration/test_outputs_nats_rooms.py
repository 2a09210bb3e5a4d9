"""Many rooms through NATS leaf nodes, as docs/outputs.md configures them, with real
``nats-server`` processes: two rooms' NATS servers joined to a hub as leaf nodes, each room's
output publishing to its own server; a subscriber at the hub gets every frame of both rooms,
a late subscriber at the hub replays one room's JetStream history by its domain, and a client
of the hub's WebSocket listener (the NATS protocol over WebSocket, as ``nats.ws`` in a browser)
gets the frames too. Skips without ``nats-server``, fails under CI."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import nats
import pytest
from websockets.sync.client import connect

from skelfuse.server.output_nats import History, room_subject
from skelfuse.server.outputs import QueuedOutput
from tests.integration.test_outputs_nats import (
    FRAMES,
    NatsServer,
    Subscriber,
    _publish,
    _started,
    _wait,
    nats_server_binary,
)
from tests.support import free_port
from tests.unit.test_outputs_osc import fused_frames


class Hub:
    def __init__(self, servers: list[NatsServer], websocket_port: int) -> None:
        self.hub, self.rooms = servers[0], servers[1:]
        self.websocket_port = websocket_port


@pytest.fixture
def hub(tmp_path: Path) -> Iterator[Hub]:
    binary = nats_server_binary()
    leaf, websocket = free_port(), free_port()
    hub_extra = (
        f"leafnodes {{ listen: 127.0.0.1:{leaf} }}\n"
        f'websocket {{ listen: "127.0.0.1:{websocket}", no_tls: true }}'
    )
    remote = f'leafnodes {{ remotes: [ {{ url: "nats-leaf://127.0.0.1:{leaf}" }} ] }}'
    servers = [NatsServer(binary, tmp_path / "hub", "hub", hub_extra)]
    servers += [NatsServer(binary, tmp_path / r, r, remote) for r in ("hall-a", "hall-b")]
    try:
        for server in servers:
            server.start()
        yield Hub(servers, websocket)
    finally:
        for server in servers:
            server.stop()


def test_a_hub_gets_every_room_and_replays_a_room_by_its_domain(hub: Hub) -> None:
    frames = fused_frames()
    everyone = Subscriber(hub.hub.url, "skelfuse.*.frames")
    room_a, room_b = hub.rooms
    outputs: list[QueuedOutput] = [
        _started(room_a.url, "hall-a", History(max_age_s=10.0)),
        _started(room_b.url, "hall-b"),
    ]
    # The leaf links carry a subject once the hub's interest has reached the room's server.
    probe = frames[:1]
    _wait(lambda: _probed(outputs, probe, everyone), 10.0, "the hub's subscription at the rooms")
    everyone.messages.clear()
    everyone.subjects.clear()
    with connect(f"ws://127.0.0.1:{hub.websocket_port}", open_timeout=10) as ws:
        ws.recv(timeout=10)  # INFO
        ws.send(b'CONNECT {"verbose":false,"protocol":1}\r\nSUB skelfuse.*.frames 1\r\nPING\r\n')
        received = b""
        while b"PONG" not in received:
            received += _bytes(ws.recv(timeout=10))
        for output in outputs:
            _publish(output, frames)
        _wait(lambda: len(everyone.messages) >= 2 * FRAMES, 10.0, "both rooms at the hub")
        received = b""
        deadline = time.monotonic() + 10.0
        while received.count(b"MSG skelfuse.") < 2 * FRAMES and time.monotonic() < deadline:
            received += _bytes(ws.recv(timeout=10))
    for output in outputs:
        output.close()
    everyone.close()

    by_room: dict[str, list[int]] = {"hall-a": [], "hall-b": []}
    for message, subject in zip(everyone.messages, everyone.subjects, strict=True):
        by_room[subject.split(".")[1]].append(message["seq"])
    for room, seqs in by_room.items():  # a late probe may come first
        assert seqs[-FRAMES:] == [f.seq for f in frames], room
        assert len(seqs) <= FRAMES + 1, room
    assert received.count(b"MSG skelfuse.hall-a.frames") == FRAMES
    assert received.count(b"MSG skelfuse.hall-b.frames") == FRAMES
    replayed = asyncio.run(_replay(hub.hub.url, "hall-a"))
    assert set(replayed[:-FRAMES]) == {probe[0].seq}  # the probes, then every frame
    assert replayed[-FRAMES:] == [f.seq for f in frames]


def _bytes(data: str | bytes) -> bytes:
    return data if isinstance(data, bytes) else data.encode()


def _probed(outputs: list[QueuedOutput], probe: list[Any], subscriber: Subscriber) -> bool:
    """Publish ``probe`` from each room (once per call) and say whether both have arrived."""
    for output in outputs:
        _publish(output, probe)
    time.sleep(0.1)
    return {s.split(".")[1] for s in subscriber.subjects} >= {"hall-a", "hall-b"}


async def _replay(hub_url: str, room: str) -> list[int]:
    """A late subscriber at the hub: the seqs of ``room``'s whole JetStream history, read
    through the hub by the room's domain."""
    client = await nats.connect(hub_url)
    js = client.jetstream(domain=room)
    count = (await js.stream_info(f"skelfuse-{room}")).state.messages
    subscription = await js.subscribe(room_subject(room), ordered_consumer=True)
    seqs = []
    for _ in range(count):
        message = await subscription.next_msg(timeout=5)
        seqs.append(msgpack.unpackb(message.data)["seq"])
    await client.close()
    return seqs
