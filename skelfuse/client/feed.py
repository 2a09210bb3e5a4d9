"""The async feed client: typed frames from a skelfuse server's WebSocket feed, reconnecting.

::

    async with FeedClient("http://127.0.0.1:8000", token=token, rotations=True) as feed:
        async for frame in feed:
            for person in frame.persons:
                print(person.id, person.joints[JointId.HEAD])

It reads one message at a time from the socket (``max_queue`` 1): the server sends the newest
frame each time a client reads (docs/api.md, "Slow clients"), and a library queue of 16 would
hand a slow app frames up to half a second old. When the connection drops (a server restart, an
eviction for reading too slowly) it connects again after a growing pause (:class:`Backoff`),
reads the skeleton message again and goes on; a refused handshake (a wrong token) ends it with
:class:`FeedRefused`. It connects directly, never through an HTTP proxy from the environment
(the feed is on the local network).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from types import TracebackType

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from skelfuse.client.connection import (
    DEFAULT_BACKOFF,
    Backoff,
    FeedRefused,
    FeedUnavailable,
    Format,
    feed_url,
    redact,
    refused_status,
)
from skelfuse.client.frames import Frame, Skeleton, decode, frame_from, skeleton_from

MAX_MESSAGE_BYTES = 2**22
"""Frames with every sensor's raw bodies grow with sensors and people; 4 MiB is far above."""
CONNECT_ERRORS = (OSError, TimeoutError, InvalidHandshake, ConnectionClosed)
"""What a connection attempt ends with when nobody answers, or not yet, or it broke."""


class FeedClient:
    """Reads the feed as :class:`~skelfuse.client.frames.Frame` objects (async).

    Args:
        server: ``http://host:port`` (or a ws:// or full feed URL; :func:`feed_url`).
        token: the server's token, if it runs with ``--token``.
        format: ``json`` (the browsers' variant: the server encodes each variant once per
            frame, so sharing it costs the server nothing) or ``msgpack``.
        raw: also receive every sensor's own bodies (``Frame.raw``).
        rotations: also receive joint rotations (``Person.rotations``).
        reconnect: connect again when the connection fails or drops; False raises instead.
        backoff: pauses between attempts.
        sleep: how to wait (tests pass a fake).
        clock: wall clock for ``Frame.received`` (Unix seconds).
        open_timeout_s: one handshake's time limit.
    """

    def __init__(
        self,
        server: str,
        *,
        token: str | None = None,
        format: Format = "json",
        raw: bool = False,
        rotations: bool = False,
        reconnect: bool = True,
        backoff: Backoff = DEFAULT_BACKOFF,
        sleep: Callable[[float], Awaitable[None]] = asyncio.sleep,
        clock: Callable[[], float] = time.time,
        open_timeout_s: float = 10.0,
    ) -> None:
        self.url = feed_url(server, token=token, format=format, raw=raw, rotations=rotations)
        self.reconnect = reconnect
        self.backoff = backoff
        self.skeleton: Skeleton | None = None
        """The skeleton message of the current connection."""
        self.connections = 0
        """Connections that got their greeting (more than one: it reconnected)."""
        self._sleep = sleep
        self._clock = clock
        self._open_timeout_s = open_timeout_s
        self._socket: ClientConnection | None = None
        self._closed = False

    async def __aenter__(self) -> FeedClient:
        await self.connect()
        return self

    async def __aexit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        await self.close()

    def __aiter__(self) -> FeedClient:
        return self

    async def __anext__(self) -> Frame:
        try:
            return await self.next_frame()
        except FeedUnavailable:
            if self.closed:  # by close(), perhaps while this waited
                raise StopAsyncIteration from None
            raise

    async def connect(self) -> Skeleton:
        """Connect (again) and read the skeleton message, trying as :attr:`backoff` says.

        Raises:
            FeedRefused: the server refused the handshake (4xx: token, origin, parameters).
            FeedUnavailable: no connection, and no more tries (or ``reconnect`` is False).
        """
        delays = self.backoff.delays()
        while True:
            try:
                socket = await connect(
                    self.url, compression=None, max_size=MAX_MESSAGE_BYTES, max_queue=1,
                    open_timeout=self._open_timeout_s, proxy=None,
                )  # fmt: skip
                try:
                    self.skeleton = skeleton_from(decode(await socket.recv()))
                except BaseException:
                    await socket.close()
                    raise
            except CONNECT_ERRORS as exc:
                status = refused_status(exc)
                if status is not None:
                    raise FeedRefused(status, self.url) from exc
                delay = next(delays, None) if self.reconnect else None
                if delay is None:
                    raise FeedUnavailable(f"no feed at {redact(self.url)}: {exc}") from exc
                await self._sleep(delay)
                continue
            self._socket = socket
            self.connections += 1
            return self.skeleton

    async def next_frame(self) -> Frame:
        """The next fused frame (messages of other types are skipped, as docs/api.md asks).

        Raises:
            FeedRefused, FeedUnavailable: as :meth:`connect`, when the connection dropped.
            FeedUnavailable: also when it dropped and ``reconnect`` is False, or after
                :meth:`close`.
            ValueError: a message that is not JSON or msgpack.
        """
        while True:
            if self.closed:
                raise FeedUnavailable("the client was closed")
            if self._socket is None:
                await self.connect()
            assert self._socket is not None
            try:
                message = await self._socket.recv()
            except ConnectionClosed as exc:
                self._socket = None
                if not self.reconnect:
                    raise FeedUnavailable(f"the feed closed: {exc}") from exc
                continue
            received = self._clock()
            data = decode(message)
            if data.get("type") == "frame":
                return frame_from(data, received)

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    async def close(self) -> None:
        """Close the connection; iteration then ends."""
        self._closed = True
        socket, self._socket = self._socket, None
        if socket is not None:
            await socket.close()
