"""WebSocket fan-out: every client gets its own small queue and sender task.

Fusion never waits for a client. Each client has a bounded queue (newest frames win: when it is
full the oldest queued frame is dropped and counted); its own task sends with a timeout, and a
client that cannot take a message within ``ws_send_timeout_s`` is disconnected. Each fused
frame is encoded once per (format, raw) variant, however many clients want it.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import count
from typing import Any

import msgpack

from skelfuse.fusion.hub import FusedFrame
from skelfuse.protocol.feed import frame_json

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Variant:
    binary: bool  # msgpack instead of JSON
    raw: bool  # include every sensor's raw bodies


def encode_message(message: dict[str, Any], binary: bool) -> bytes | str:
    if binary:
        packed: bytes = msgpack.packb(message, use_bin_type=True)
        return packed
    # allow_nan=False: a NaN reaching this point is a bug, and browsers reject bare NaN.
    return json.dumps(message, allow_nan=False, separators=(",", ":"))


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

    def offer(self, payload: bytes | str, now: float) -> None:
        """Queue without ever blocking: drop the oldest frame when the client is behind.

        A client whose queue stays full for ``stall_limit_s`` is marked stalled. This does not
        wait for a send to time out, which takes as long as the kernel's socket buffer (megabytes,
        tens of seconds of frames) keeps accepting data nobody reads.
        """
        if self.queue.full():
            if self.full_since is None:
                self.full_since = now
            elif now - self.full_since > self.stall_limit_s:
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
    clients: dict[int, Client] = field(default_factory=dict)
    evicted: int = 0
    published: int = 0
    _ids: count[int] = field(default_factory=lambda: count(1))

    def add(
        self, variant: Variant, remote: str, now_s: float, stall_limit_s: float = 5.0
    ) -> Client:
        client = Client(
            next(self._ids),
            variant,
            asyncio.Queue(self.queue_size),
            connected_at_s=now_s,
            remote=remote,
            stall_limit_s=stall_limit_s,
        )
        self.clients[client.client_id] = client
        return client

    def remove(self, client: Client) -> None:
        self.clients.pop(client.client_id, None)

    def publish(self, frame: FusedFrame) -> None:
        """Hand one fused frame to every client (encoded once per variant)."""
        self.published += 1
        now = time.monotonic()
        cache: dict[Variant, bytes | str] = {}
        for client in list(self.clients.values()):
            payload = cache.get(client.variant)
            if payload is None:
                payload = encode_message(
                    frame_json(frame, client.variant.raw, time.time()), client.variant.binary
                )
                cache[client.variant] = payload
            client.offer(payload, now)

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
    send: Callable[[bytes | str], Any],
    timeout_s: float,
) -> None:
    """Send queued frames to one client until it fails or stalls for ``timeout_s``."""
    while True:
        payload = await client.queue.get()
        await asyncio.wait_for(send(payload), timeout=timeout_s)
        client.sent += 1
        client.full_since = None
