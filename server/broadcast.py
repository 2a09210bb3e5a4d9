"""WebSocket fan-out: every client gets its own small queue and sender task.

Fusion never waits for a client. Each client has a bounded queue (newest frames win: when it is
full the oldest queued frame is dropped and counted); its own task sends with a timeout, and a
client that cannot take a message within ``send_timeout_s`` (``ws_send_timeout_s``), or whose
queue stays full that long, is disconnected. Each fused frame is encoded once per (format, raw)
variant, however many clients want it, and that one text or bytes object is what every such
client's queue holds. JSON is encoded by orjson (about a tenth of ``json.dumps``'s time), whose
output for feed messages is the same text as ``json.dumps(..., separators=(",", ":"))`` except
that non-ASCII is written as UTF-8, not ``\\u`` escapes, and NaN or infinity become ``null``.

The socket is anything with :class:`FeedSocket`'s three methods (the app adapts Starlette's
WebSocket), so this module is tested with a fake one.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from itertools import count
from typing import Any, Protocol

import msgpack
import orjson
from starlette.websockets import WebSocketDisconnect

from skelfuse.fusion.hub import FusedFrame
from skelfuse.protocol.feed import frame_json

logger = logging.getLogger(__name__)

STALLED_CLOSE_CODE = 1008
CLOSE_WAIT_S = 1.0
"""How long a stalled client's close frame may take: it may never leave a full socket buffer."""


@dataclass(frozen=True, slots=True)
class Variant:
    binary: bool  # msgpack instead of JSON
    raw: bool  # include every sensor's raw bodies


class FeedSocket(Protocol):
    """One client's connection, as the broadcaster uses it."""

    async def send(self, payload: bytes | str) -> None:
        """Send one message (bytes: a binary message; str: a text message)."""
        ...

    async def closed(self) -> None:
        """Return when the client has disconnected (reading and ignoring what it sends)."""
        ...

    async def close(self, code: int, reason: str) -> None:
        """Close the connection with a WebSocket close code."""
        ...


def encode_message(message: dict[str, Any], binary: bool) -> bytes | str:
    """One feed message as sent: msgpack bytes, or compact JSON text.

    JSON never holds a bare NaN (browsers reject it): the feed builders already send ``null`` for
    unknown joints, and orjson writes any other NaN or infinity as ``null`` too, as JavaScript's
    ``JSON.stringify`` does, instead of failing the fusion loop. numpy scalars are written as
    numbers.

    Raises:
        TypeError: a value JSON or msgpack cannot represent (orjson: a dict key that is not a
            string).
    """
    if binary:
        packed: bytes = msgpack.packb(message, use_bin_type=True)
        return packed
    # Text, not bytes: a WebSocket text message. Decoding is one copy, once per frame.
    return orjson.dumps(message, option=orjson.OPT_SERIALIZE_NUMPY).decode()


@dataclass(slots=True)
class Client:
    client_id: int
    variant: Variant
    queue: asyncio.Queue[bytes | str]
    sent: int = 0
    dropped: int = 0
    connected_at_s: float = 0.0
    remote: str = ""
    stall_limit_s: float = 5.0
    full_since: float | None = None
    """When the queue was first found full with no send completed since (None: keeping up)."""
    stalled: asyncio.Event = field(default_factory=asyncio.Event)
    """Set when the client has taken nothing for ``stall_limit_s``: it is to be disconnected."""

    def offer(self, payload: bytes | str, now_mono: float) -> None:
        """Queue without ever blocking: drop the oldest frame when the client is behind.

        A client whose queue stays full for ``stall_limit_s`` (``now_mono``: monotonic seconds)
        is marked stalled. This does not wait for a send to time out, which takes as long as the
        kernel's socket buffer (megabytes, tens of seconds of frames) keeps accepting data
        nobody reads.
        """
        if self.queue.full():
            if self.full_since is None:
                self.full_since = now_mono
            elif now_mono - self.full_since > self.stall_limit_s:
                self.stalled.set()
            try:
                self.queue.get_nowait()
                self.dropped += 1
            except asyncio.QueueEmpty:
                pass
        self.queue.put_nowait(payload)


@dataclass(slots=True)
class Broadcaster:
    queue_size: int = 2
    send_timeout_s: float = 5.0
    clients: dict[int, Client] = field(default_factory=dict)
    evicted: int = 0
    published: int = 0
    _ids: count[int] = field(default_factory=lambda: count(1))

    def add(self, variant: Variant, remote: str, now_s: float) -> Client:
        """Register a client (``now_s``: Unix seconds, its connection time)."""
        client = Client(
            next(self._ids),
            variant,
            asyncio.Queue(self.queue_size),
            connected_at_s=now_s,
            remote=remote,
            stall_limit_s=self.send_timeout_s,
        )
        self.clients[client.client_id] = client
        return client

    def remove(self, client: Client) -> None:
        self.clients.pop(client.client_id, None)

    def publish(self, frame: FusedFrame, now_s: float, now_mono: float) -> None:
        """Hand one fused frame to every client (encoded once per variant).

        ``now_s``: Unix seconds, the message's ``t_sent``; ``now_mono``: monotonic seconds, for
        the stall check.
        """
        self.published += 1
        cache: dict[Variant, bytes | str] = {}
        for client in list(self.clients.values()):
            payload = cache.get(client.variant)
            if payload is None:
                payload = encode_message(
                    frame_json(frame, client.variant.raw, now_s), client.variant.binary
                )
                cache[client.variant] = payload
            client.offer(payload, now_mono)

    async def serve(self, client: Client, socket: FeedSocket, greeting: bytes | str) -> None:
        """Send ``greeting``, then the client's frames until it disconnects, fails or stalls.

        A client that stalls (its queue full for ``send_timeout_s``, or one send taking that
        long) is counted in :attr:`evicted` and closed with code 1008 "client too slow". The
        client is removed however this ends.
        """
        try:
            await asyncio.wait_for(socket.send(greeting), self.send_timeout_s)
        except (WebSocketDisconnect, RuntimeError, TimeoutError):
            self.remove(client)
            return
        sender = asyncio.create_task(pump(client, socket.send, self.send_timeout_s))
        receiver = asyncio.create_task(socket.closed())
        stalled = asyncio.create_task(client.stalled.wait())
        try:
            done, _ = await asyncio.wait(
                {sender, receiver, stalled}, return_when=asyncio.FIRST_COMPLETED
            )
            if stalled in done or (sender in done and isinstance(sender.exception(), TimeoutError)):
                self.remove(client)
                self.evicted += 1
                logger.warning("WebSocket client %s stalled; disconnected", client.remote)
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(
                        socket.close(STALLED_CLOSE_CODE, "client too slow"), CLOSE_WAIT_S
                    )
        finally:
            for task in (sender, receiver, stalled):
                task.cancel()
            await asyncio.gather(sender, receiver, stalled, return_exceptions=True)
            self.remove(client)

    def stats(self) -> list[dict[str, object]]:
        return [
            {
                "id": c.client_id,
                "remote": c.remote,
                "format": "msgpack" if c.variant.binary else "json",
                "raw": c.variant.raw,
                "sent": c.sent,
                "dropped": c.dropped,
                "queued": c.queue.qsize(),
            }
            for c in self.clients.values()
        ]


async def pump(
    client: Client,
    send: Callable[[bytes | str], Awaitable[None]],
    timeout_s: float,
) -> None:
    """Send queued frames to one client until it fails or one send takes ``timeout_s``."""
    while True:
        payload = await client.queue.get()
        # asyncio.timeout, not wait_for: on 3.11 wait_for swallows a cancellation that arrives
        # as the send completes, and the pump would then outlive its client.
        async with asyncio.timeout(timeout_s):
            await send(payload)
        client.sent += 1
        client.full_since = None
