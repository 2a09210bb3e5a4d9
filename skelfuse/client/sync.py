"""The blocking feed client, for scripts and programs without an event loop::

    with SyncFeedClient("http://127.0.0.1:8000", token=token) as feed:
        for frame in feed:
            ...

The same behaviour as :class:`skelfuse.client.feed.FeedClient` (one message read at a time,
reconnects with backoff, a refused handshake ends it), on websockets' threading client.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from types import TracebackType

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

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
from skelfuse.client.feed import CONNECT_ERRORS, MAX_MESSAGE_BYTES
from skelfuse.client.frames import Frame, Skeleton, decode, frame_from, skeleton_from


class SyncFeedClient:
    """Reads the feed as :class:`~skelfuse.client.frames.Frame` objects (blocking).

    Arguments as :class:`skelfuse.client.feed.FeedClient`; ``sleep`` is a blocking one.
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
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.time,
        open_timeout_s: float = 10.0,
    ) -> None:
        self.url = feed_url(server, token=token, format=format, raw=raw, rotations=rotations)
        self.reconnect = reconnect
        self.backoff = backoff
        self.skeleton: Skeleton | None = None
        self.connections = 0
        self._sleep = sleep
        self._clock = clock
        self._open_timeout_s = open_timeout_s
        self._socket: ClientConnection | None = None
        self._closed = False

    def __enter__(self) -> SyncFeedClient:
        self.connect()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.close()

    def __iter__(self) -> Iterator[Frame]:
        while True:
            try:
                yield self.next_frame()
            except FeedUnavailable:
                if self.closed:  # by close()
                    return
                raise

    def connect(self) -> Skeleton:
        """Connect (again) and read the skeleton message (as ``FeedClient.connect``).

        Raises:
            FeedRefused: the server refused the handshake (4xx: token, origin, parameters).
            FeedUnavailable: no connection, and no more tries (or ``reconnect`` is False).
        """
        delays = self.backoff.delays()
        while True:
            try:
                socket = connect(
                    self.url, compression=None, max_size=MAX_MESSAGE_BYTES, max_queue=1,
                    open_timeout=self._open_timeout_s, proxy=None,
                )  # fmt: skip
                # Entered as a context manager (closed by close()): websockets 17.1 warns about
                # a connection used without one, and its opt-out (legacy=True) is 17.1's only.
                socket.__enter__()
                try:
                    self.skeleton = skeleton_from(decode(socket.recv()))
                except BaseException:
                    socket.close()
                    raise
            except CONNECT_ERRORS as exc:
                status = refused_status(exc)
                if status is not None:
                    raise FeedRefused(status, self.url) from exc
                delay = next(delays, None) if self.reconnect else None
                if delay is None:
                    raise FeedUnavailable(f"no feed at {redact(self.url)}: {exc}") from exc
                self._sleep(delay)
                continue
            self._socket = socket
            self.connections += 1
            return self.skeleton

    def next_frame(self) -> Frame:
        """The next fused frame (other message types are skipped); raises as
        ``FeedClient.next_frame``."""
        while True:
            if self.closed:
                raise FeedUnavailable("the client was closed")
            if self._socket is None:
                self.connect()
            assert self._socket is not None
            try:
                message = self._socket.recv()
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

    def close(self) -> None:
        """Close the connection; iteration then ends."""
        self._closed = True
        socket, self._socket = self._socket, None
        if socket is not None:
            socket.close()
