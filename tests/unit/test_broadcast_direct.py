"""The broadcaster's cheap path (server/broadcast.py): a socket that says it can take a frame
now gets it written during ``publish``, with no task to wake; one that cannot (a send in
progress, a full socket, a paced client waiting for its pong) gets it through its mailbox and
sender as before, and a frame never overtakes another."""

from __future__ import annotations

import asyncio

from skelfuse.server.broadcast import Broadcaster, Outgoing, Variant
from skelfuse.server.histogram import Histogram
from tests.unit.test_broadcast import fused_frame

JSON = Variant(False, False)


class ReadySocket:
    """A socket with ``write_now`` and ``ready``: it takes frames at once while ``open_now``,
    and its async sends (the greeting, the mailbox's frames) end when the test lets them."""

    def __init__(self) -> None:
        self.written: list[tuple[str, int]] = []  # (how, seq)
        self.open_now = True
        self.became_ready = asyncio.Event()
        self.became_ready.set()
        self.drained = asyncio.Semaphore(0)
        self.sending = asyncio.Event()
        self.disconnected = asyncio.Event()

    def write_now(self, message: Outgoing) -> bool:
        if not self.open_now:
            return False
        self.written.append(("now", seq_of(message)))
        return True

    async def ready(self) -> None:
        await self.became_ready.wait()

    async def send(self, message: Outgoing) -> None:
        self.written.append(("send", seq_of(message)))
        self.sending.set()
        await self.drained.acquire()

    async def closed(self) -> None:
        await self.disconnected.wait()

    async def close(self, code: int, reason: str) -> None:
        pass


def seq_of(message: Outgoing) -> int:
    text = message.payload
    assert isinstance(text, str)
    return -1 if "seq" not in text else int(text.split('"seq":')[1].split(",")[0])


async def settle() -> None:
    for _ in range(5):
        await asyncio.sleep(0)


async def test_ready_clients_get_each_frame_during_publish_after_their_greeting() -> None:
    broadcaster = Broadcaster()
    clients = [broadcaster.add(JSON, str(i), 0.0) for i in range(3)]
    sockets = [ReadySocket() for _ in clients]
    serving = [
        asyncio.create_task(broadcaster.serve(client, socket, "hello"))
        for client, socket in zip(clients, sockets, strict=True)
    ]
    await settle()
    broadcaster.publish(fused_frame(1), 1000.0, 0.0)  # the greetings are still being sent
    for socket in sockets:
        socket.drained.release()  # the greeting, then frame 1 from the mailbox
        await settle()
        socket.drained.release()
    await settle()
    for seq in range(2, 6):
        broadcaster.publish(fused_frame(seq), 1000.0 + seq / 30, seq / 30)
    for client, socket in zip(clients, sockets, strict=True):
        assert socket.written == [("send", -1), ("send", 1)] + [("now", s) for s in range(2, 6)]
        assert client.sent == 5 and client.pending is None and client.conflated == 0
    for socket in sockets:
        socket.disconnected.set()
    await asyncio.gather(*serving)


async def test_a_client_that_cannot_take_a_frame_now_gets_the_newest_when_it_can() -> None:
    broadcaster = Broadcaster()
    client = broadcaster.add(JSON, "slow", 0.0)
    socket = ReadySocket()
    serving = asyncio.create_task(broadcaster.serve(client, socket, "hello"))
    socket.drained.release()
    await settle()
    broadcaster.publish(fused_frame(1), 1000.0, 0.0)
    socket.open_now = False  # its socket is full, or it is paced and its pong not back
    socket.became_ready.clear()
    for seq in (2, 3, 4):
        broadcaster.publish(fused_frame(seq), 1000.0, seq / 30)
        await settle()
    assert socket.written == [("send", -1), ("now", 1)] and client.conflated == 2
    socket.became_ready.set()  # drained: the sender takes the newest
    socket.open_now = True
    await socket.sending.wait()
    socket.drained.release()
    await settle()
    broadcaster.publish(fused_frame(5), 1000.0, 5 / 30)
    assert socket.written == [("send", -1), ("now", 1), ("send", 4), ("now", 5)]
    assert client.sent == 3
    socket.disconnected.set()
    await serving


async def test_a_frame_written_now_never_overtakes_the_sender() -> None:
    broadcaster = Broadcaster()
    client = broadcaster.add(JSON, "a", 0.0)
    socket = ReadySocket()
    serving = asyncio.create_task(broadcaster.serve(client, socket, "hello"))
    await settle()
    for seq in (1, 2):  # the greeting has not drained: nothing may be written past it
        broadcaster.publish(fused_frame(seq), 1000.0, seq / 30)
        await settle()
    assert socket.written == [("send", -1)]
    socket.drained.release()
    await settle()
    assert socket.written == [("send", -1), ("send", 2)]  # the newest, from the mailbox
    broadcaster.publish(fused_frame(3), 1000.0, 3 / 30)  # frame 2 still draining
    assert socket.written == [("send", -1), ("send", 2)] and client.pending is not None
    socket.drained.release()
    await settle()
    socket.drained.release()
    await settle()
    assert socket.written == [("send", -1), ("send", 2), ("send", 3)]
    socket.disconnected.set()
    await serving


async def test_each_frame_written_to_a_client_counts_its_age_once() -> None:
    broadcaster = Broadcaster(send_times=Histogram([1.0]))
    client = broadcaster.add(JSON, "a", 0.0)
    socket = ReadySocket()
    serving = asyncio.create_task(broadcaster.serve(client, socket, "hello"))
    socket.drained.release()  # the greeting: not a frame, not counted
    await settle()
    broadcaster.publish(fused_frame(1), 1000.0, 0.0)  # written now
    socket.open_now = False
    broadcaster.publish(fused_frame(2), 1000.0, 1 / 30)  # through the mailbox and the sender
    await socket.sending.wait()
    socket.drained.release()
    await settle()
    assert [how for how, _ in socket.written] == ["send", "now", "send"]
    assert broadcaster.send_times is not None and broadcaster.send_times.count == 2
    socket.disconnected.set()
    await serving
