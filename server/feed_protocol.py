"""uvicorn's WebSocket protocol with send buffers of about one frame, for a live feed.

uvicorn writes each message into the connection at once: a send returns as soon as the kernel
has taken the bytes, and Linux lets a TCP socket's send buffer grow to megabytes on loopback
(``net.ipv4.tcp_wmem``), so a client that reads slowly finds seconds of old frames waiting for
it in the kernel, whatever the application does (issue 12, defect 2: 5-6.5 s old frames, 1-2
MiB per stalled client). :class:`FeedWebSocketProtocol` keeps that queue out of the kernel and
out of the transport, so that conflation in ``server/broadcast.py`` decides what a slow client
gets:

- ``TCP_NOTSENT_LOWAT`` (``NOTSENT_LOWAT_BYTES``): the kernel takes new bytes only while less
  than that much is waiting to be sent, instead of up to the send buffer's size;
- the transport's high-water mark is 0, so the protocol pauses writing as soon as the kernel
  refuses a byte;
- a ``websocket.send`` returns only once the transport's buffer has drained into the kernel
  (or the connection is lost). The broadcaster takes the newest frame only after that, so
  frames wait in its one-slot mailbox, where a newer frame replaces them, not in a buffer;
- a client that reads more slowly than the feed is paced (``server/feed_pacing.py``): each
  frame is followed by a ping and its send returns when the pong is back, i.e. once the client
  has read that far. Without that the client's own receive buffer, which Linux grows to
  hundreds of KiB, would still hold a queue of old frames in front of each read. Clients that
  keep up answer a ping every ``Pacer.ping_every`` frames and are never held.

A close is written even while writing is paused (the closing handshake would otherwise wait
behind a full socket forever), and a connection whose peer has not answered the close after
``close_timeout`` is aborted rather than left to flush a buffer nobody reads.

``skelfuse server`` runs uvicorn with this class (``skelfuse.cli.server.uvicorn_config``); an
application embedding the app in another server keeps the broadcaster's conflation and eviction,
with the kernel's buffers in front of them.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
from asyncio import BaseTransport, Transport
from typing import Any, cast

from uvicorn._types import ASGISendEvent
from uvicorn.protocols.utils import ClientDisconnected
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from websockets.exceptions import InvalidState
from websockets.frames import Frame
from websockets.http11 import Request
from websockets.protocol import State

from skelfuse.server.broadcast import PREFRAMED
from skelfuse.server.feed_pacing import Pacer

TCP_NOTSENT_LOWAT = getattr(socket, "TCP_NOTSENT_LOWAT", 25)
"""The option's number on Linux (25), where Python's socket module lacks the name."""
NOTSENT_LOWAT_BYTES = 1
"""Unsent bytes above which the kernel refuses more: one byte means "only when all is sent",
so at most the frame being written waits in the kernel, never a second one behind it."""
ABORT_AFTER_CLOSE_S = 2.0
"""After uvicorn's close timeout, how long a connection may still flush before it is aborted."""


class FeedWebSocketProtocol(WebSocketsSansIOProtocol):
    """uvicorn's sans-I/O websockets protocol with about one frame of send buffering."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.pacer = Pacer()
        self._ping_count = 0
        self._ping_payload: bytes | None = None
        self._pong = asyncio.Event()
        self._held = False
        """A paced client's pong has not come back yet: no frame may be written."""

    def connection_made(self, transport: BaseTransport) -> None:
        """Set the small limits on a new connection (see the module's docstring)."""
        super().connection_made(transport)
        tcp = cast(Transport, transport)
        sock = tcp.get_extra_info("socket")
        if sock is not None:
            # Not every platform has the option (it is Linux and macOS): then the kernel's own
            # buffer stays in front of the mailbox, and only eviction bounds it.
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, TCP_NOTSENT_LOWAT, NOTSENT_LOWAT_BYTES)
        tcp.set_write_buffer_limits(high=0, low=0)

    def handle_connect(self, event: Request) -> None:
        """Accept as uvicorn does; offer pre-framed sends when no extension changes the framing
        (permessage-deflate compresses each message per connection)."""
        super().handle_connect(event)
        if self.handshake_initiated and not self.handshake_complete and not self.conn.extensions:
            self.scope.setdefault("extensions", {})[PREFRAMED] = {
                "write_now": self.write_now,
                "ready": self.ready,
            }

    def write_now(self, framed: bytes) -> bool:
        """Write a pre-framed data message at once if the connection can take it without
        queueing (open, drained, not waiting for a pacing pong); False, and nothing written,
        if not. What follows every frame follows it (the pacing ping). The broadcaster's cheap
        path: no task, no ASGI message, per client and frame.
        """
        if (
            self._held
            or not self.writable.is_set()
            or self.disconnected
            or self.close_sent
            or self.conn.state is not State.OPEN
        ):
            return False
        self.transport.write(framed)
        self._after_frame()
        return True

    async def ready(self) -> None:
        """Return once :meth:`write_now` could write (or the connection is gone: then a send
        fails)."""
        await self.writable.wait()
        if self._held and not self.disconnected:
            await self._pong.wait()

    def _after_frame(self) -> None:
        """A frame has been written: the pacing ping after it, and hold the next frame for the
        pong if the client is paced."""
        ping, wait = self.pacer.after_frame(self.loop.time())
        if ping:
            self._ping()
        self._held = wait and not self._pong.is_set()

    async def send(self, message: ASGISendEvent) -> None:
        """Send as uvicorn does; a data message returns once it has left the transport.

        ``{"type": "websocket.send", PREFRAMED: bytes}`` writes a message framed by the caller
        (one framing shared by every client, ``server/broadcast.py``), when the scope offers it.

        Raises:
            uvicorn.protocols.utils.ClientDisconnected: the client is gone.
            RuntimeError: a message the ASGI WebSocket protocol does not allow now.
        """
        framed = cast(dict[str, Any], message).get(PREFRAMED)
        if message["type"] == "websocket.close" and self.handshake_complete:
            # uvicorn waits for the transport to be writable before anything, the close too;
            # a client that stopped reading never makes it writable again.
            self.writable.set()
        if isinstance(framed, bytes) and message["type"] == "websocket.send":
            await self.writable.wait()
            if self.disconnected or self.close_sent or self.conn.state is not State.OPEN:
                raise ClientDisconnected()
            self.transport.write(framed)
        else:
            await super().send(message)
        if message["type"] == "websocket.send":
            await self.writable.wait()  # set again by resume_writing or connection_lost
            self._after_frame()
            if self._held and not self.disconnected:
                await self._pong.wait()
        elif message["type"] == "websocket.close" and self.close_timer is not None:
            self.close_timer.cancel()
            self.close_timer = self.loop.call_later(self.close_timeout, self._give_up)

    def pause_writing(self) -> None:
        """The kernel refused bytes: the client reads more slowly than we send."""
        super().pause_writing()
        if self.handshake_complete:
            self.pacer.on_full()

    def connection_lost(self, exc: Exception | None) -> None:
        super().connection_lost(exc)
        self._held = False
        self._pong.set()  # a send waiting for a pong returns; the next one fails

    def handle_pong(self, event: Frame) -> None:
        if self._ping_payload is not None and bytes(event.data) == self._ping_payload:
            self._ping_payload = None
            self.pacer.on_pong(self.loop.time())
            self._held = False
            self._pong.set()
            return
        super().handle_pong(event)  # the keepalive's

    def _ping(self) -> None:
        """Write a ping after the frame just written."""
        self._ping_count += 1
        payload = b"feed" + struct.pack("!I", self._ping_count & 0xFFFFFFFF)
        try:
            self.conn.send_ping(payload)
        except InvalidState:  # closing: nothing more will be read
            self.pacer.on_pong(self.loop.time())
            return
        self._ping_payload = payload
        self._pong.clear()
        self.transport.write(b"".join(self.conn.data_to_send()))

    def _give_up(self) -> None:
        """The peer never answered the close: close, and abort if the buffer cannot flush."""
        self.close_timer = None
        self.transport.close()
        self.loop.call_later(ABORT_AFTER_CLOSE_S, self._abort)

    def _abort(self) -> None:
        if not self.disconnected:
            self.transport.abort()
