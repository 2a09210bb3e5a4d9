"""WebSocket fan-out: a live feed that conflates. Every client gets a one-frame mailbox and a
sender task.

Fusion never waits for a client. Publishing puts the frame in every client's mailbox, replacing
one the client has not taken yet (counted as ``conflated``); each client's sender takes the
newest frame only once its previous send has drained (``server/feed_protocol.py`` keeps the
socket's buffers to about one frame), so a slow client gets the newest frame at its own pace,
never a queue of old ones, and a client that keeps up gets every frame. A client for which a
frame has waited ``send_timeout_s`` (``ws_send_timeout_s``, 5 s), or whose greeting takes that
long, is closed with code 1008 and counted as evicted.

Each fused frame is encoded once per (format, raw, rotations) variant, however many clients
want it, and that one text or bytes object, with its WebSocket framing, is what every such
client's mailbox holds (a server that takes pre-framed messages, ``PREFRAMED``, writes the
framing as is). The persons' joint rotations are computed once per frame, only when a client
asked for them (``recording/joint_orientations.py``). JSON is encoded by orjson (about a tenth
of ``json.dumps``'s time), whose output for feed messages is the same text as
``json.dumps(..., separators=(",", ":"))`` except that non-ASCII is written as UTF-8, not ``\\u``
escapes, and NaN or infinity become ``null``.

The socket is anything with :class:`FeedSocket`'s three methods (the app adapts Starlette's
WebSocket), so this module is tested with a fake one.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from itertools import count
from typing import Any, Protocol

import msgpack
import numpy as np
import orjson
from pydantic import BaseModel, ConfigDict
from websockets.frames import Frame, Opcode

from skelfuse.fusion.engine import FusedFrame
from skelfuse.fusion.views import FusedPerson
from skelfuse.protocol.feed import frame_json
from skelfuse.recording.joint_orientations import Orientations, orientations
from skelfuse.server.histogram import Histogram

logger = logging.getLogger(__name__)

PREFRAMED = "skelfuse.preframed"
"""ASGI scope extension of a server that takes ``{"type": "websocket.send", PREFRAMED: bytes}``:
a whole WebSocket message, framed once and written as is (``server/feed_protocol.py``)."""
STALLED_CLOSE_CODE = 1008
CLOSE_WAIT_S = 1.0
"""How long a stalled client's close frame may take: it may never leave a full socket buffer."""


@dataclass(frozen=True, slots=True)
class Variant:
    binary: bool  # msgpack instead of JSON
    raw: bool  # include every sensor's raw bodies
    rotations: bool = False  # include the persons' joint rotations (docs/api.md, "Rotations")


class PersonsQuery(BaseModel):
    """``GET /api/persons``'s query: ``?rotations=1`` adds the joint rotations, as on the feed.
    Other parameters are ignored, as on every route (a browser's cache buster, a token put in
    the query by mistake); ``schemathesis.toml`` says so for the negative checks."""

    model_config = ConfigDict(extra="ignore")
    rotations: bool = False


def persons_orientations(persons: Sequence[FusedPerson]) -> Orientations | None:
    """The joint rotations of a frame's persons, in their order (None for no person)."""
    if not persons:
        return None
    return orientations(np.stack([p.joints for p in persons]))


@dataclass(frozen=True, slots=True)
class Outgoing:
    """One message for clients: its payload, and the same message framed for the wire."""

    payload: bytes | str
    framed: bytes
    """The unmasked WebSocket message (header and payload) a server without extensions sends:
    framed once per frame and variant, not once per client."""
    published_s: float | None = None
    """``time.perf_counter()`` when its frame's publishing began (None: not a frame)."""


def outgoing(payload: bytes | str, published_s: float | None = None) -> Outgoing:
    """``payload`` with its WebSocket framing (binary for bytes, text for str); ``published_s``:
    :attr:`Outgoing.published_s`."""
    if isinstance(payload, bytes):
        frame = Frame(Opcode.BINARY, payload)
    else:
        frame = Frame(Opcode.TEXT, payload.encode())
    return Outgoing(payload, frame.serialize(mask=False), published_s)


class FeedSocket(Protocol):
    """One client's connection, as the broadcaster uses it.

    A socket may also have ``write_now(message: Outgoing) -> bool`` and ``async ready()``
    (the app's, on ``skelfuse server``'s uvicorn protocol): ``write_now`` writes the message
    at once if the connection can take it without queueing, else says False and writes
    nothing; ``ready`` returns once it could. With them, :meth:`Broadcaster.publish` writes
    each frame straight into every client that is ready, in one loop, and only the others
    go through their mailbox and sender task.
    """

    async def send(self, message: Outgoing) -> None:
        """Send one message (a bytes payload: a binary message; str: a text message)."""
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
    connected_at_s: float = 0.0
    remote: str = ""
    stall_limit_s: float = 5.0
    pending: Outgoing | None = None
    """The mailbox: the newest frame the sender has not taken yet (None: nothing waiting)."""
    waiting_since: float | None = None
    """Monotonic seconds when a frame last found the mailbox empty and has waited since (None:
    the client has taken everything offered)."""
    sent: int = 0
    conflated: int = 0
    """Frames replaced in the mailbox by a newer one before the client could take them."""
    busy: bool = True
    """The sender task is sending (the greeting, from the start) or about to send: a frame
    written past it could overtake the one it sends."""
    write_now: Callable[[Outgoing], bool] | None = None
    """The socket's ``write_now`` (:class:`FeedSocket`), or None."""
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    stalled: asyncio.Event = field(default_factory=asyncio.Event)
    """Set when a frame has waited for the client over ``stall_limit_s``: it is to be closed."""

    def offer(self, payload: Outgoing, now_mono: float) -> None:
        """Put the newest frame in the mailbox without ever blocking; it replaces an untaken one.

        A frame that has waited in the mailbox for more than ``stall_limit_s`` (``now_mono``:
        monotonic seconds) marks the client stalled. This does not wait for a send to time out:
        the sender may be blocked on a socket that will never drain.
        """
        if self.pending is None:
            self.waiting_since = now_mono
        else:
            self.conflated += 1
            if (
                self.waiting_since is not None
                and now_mono - self.waiting_since > self.stall_limit_s
            ):
                self.stalled.set()
        self.pending = payload
        self.ready.set()

    def take(self) -> Outgoing | None:
        """Empty the mailbox (the sender's side): the newest frame, or None if none waits."""
        payload, self.pending = self.pending, None
        self.waiting_since = None
        self.ready.clear()
        return payload


@dataclass(slots=True)
class Broadcaster:
    send_timeout_s: float = 5.0
    """A client that has not taken a frame for this long is closed with 1008 and counted."""
    clients: dict[int, Client] = field(default_factory=dict)
    evicted: int = 0
    published: int = 0
    send_times: Histogram | None = None
    """Where each frame's age is counted as it is written into a client's socket (seconds from
    the start of :meth:`publish`, as the message's ``t_sent``): the server's share of what a
    client measures, without the client's own (``server/stage_timing.py``, stage ``send``)."""
    _ids: count[int] = field(default_factory=lambda: count(1))

    def add(self, variant: Variant, remote: str, now_s: float) -> Client:
        """Register a client (``now_s``: Unix seconds, its connection time)."""
        client = Client(
            next(self._ids),
            variant,
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
        started = time.perf_counter()
        self.published += 1
        send_times = self.send_times
        cache: dict[Variant, Outgoing] = {}
        rotations: list[Orientations | None] = []  # computed once, for the first that asks
        for client in list(self.clients.values()):
            variant = client.variant
            message = cache.get(variant)
            if message is None:
                if variant.rotations and not rotations:
                    rotations.append(persons_orientations(frame.persons))
                built = frame_json(
                    frame, variant.raw, now_s, rotations[0] if variant.rotations else None
                )
                message = outgoing(encode_message(built, variant.binary), started)
                cache[variant] = message
            # The cheap path, for every client that keeps up: the frame goes into its socket
            # here, with no task to wake. Otherwise (a send in progress, a full socket, a paced
            # client waiting for its pong) the mailbox, and the client's sender takes it.
            write_now = client.write_now
            if write_now is not None and client.pending is None and not client.busy:
                try:
                    written = write_now(message)
                except Exception:  # a connection in a state not foreseen: the usual path
                    logger.debug("direct write to %s failed", client.remote, exc_info=True)
                    written = False
                if written:
                    client.sent += 1
                    if send_times is not None:
                        send_times.record(time.perf_counter() - started)
                    continue
            client.offer(message, now_mono)

    async def serve(self, client: Client, socket: FeedSocket, greeting: bytes | str) -> None:
        """Send ``greeting``, then the client's frames until it disconnects, fails or stalls.

        A client that stalls (a frame waiting in its mailbox for ``send_timeout_s``, or its
        greeting taking that long) is counted in :attr:`evicted` and closed with code
        1008 "client too slow". The client is removed however this ends.
        """
        ready: Callable[[], Awaitable[None]] | None = getattr(socket, "ready", None)
        sender = asyncio.create_task(
            pump(
                client, socket.send, self.send_timeout_s, outgoing(greeting), ready,
                self.send_times,
            )
        )  # fmt: skip
        client.write_now = getattr(socket, "write_now", None)
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
                "rotations": c.variant.rotations,
                "sent": c.sent,
                "conflated": c.conflated,
                "dropped": c.conflated,  # the name before conflation, kept for existing readers
                "waiting": c.pending is not None,
            }
            for c in self.clients.values()
        ]


async def pump(
    client: Client,
    send: Callable[[Outgoing], Awaitable[None]],
    timeout_s: float,
    greeting: Outgoing | None = None,
    ready: Callable[[], Awaitable[None]] | None = None,
    send_times: Histogram | None = None,
) -> None:
    """Send ``greeting`` (if any; it fails after ``timeout_s``), then the newest frame each time
    the previous send is done, until a send fails.

    ``ready`` (the socket's, :class:`FeedSocket`) is awaited before a frame is taken from the
    mailbox, so that the frame taken is the newest when the socket can take it. The client is
    :attr:`Client.busy` from the start until the greeting is sent, and from a wake-up until
    the frame is sent. Each frame's age as its send begins goes into ``send_times``.

    ``send`` should return once its message has drained from the server's buffers (as
    ``server/feed_protocol.py`` makes uvicorn's do): the frame taken next is then the newest at
    that moment, and the frames published meanwhile were conflated in the mailbox. A frame send
    has no timer of its own (one per client and frame costs): while frames are published, the
    mailbox's stall check ends a send that never returns; when none are, it costs nothing.

    Raises:
        TimeoutError: the greeting took ``timeout_s``.
    """
    client.busy = True
    if greeting is not None:
        # asyncio.timeout, not wait_for: on 3.11 wait_for swallows a cancellation that arrives
        # as the send completes, and the pump would then outlive its client.
        async with asyncio.timeout(timeout_s):
            await send(greeting)
    while True:
        client.busy = False
        await client.ready.wait()
        client.busy = True
        if ready is not None:
            await ready()
        message = client.take()
        if message is None:
            continue
        if send_times is not None and message.published_s is not None:
            send_times.record(time.perf_counter() - message.published_s)
        await send(message)
        client.sent += 1
