"""The NATS output: each fused frame, as the WebSocket feed's msgpack message, published to
``skelfuse.<room>.frames`` (docs/outputs.md, "NATS").

nats-py is asyncio: the sink runs its client on an event loop in a thread of its own, and the
output's thread (:class:`~skelfuse.server.outputs.QueuedOutput`) hands each frame over and waits
for the publish (which only appends to the client's buffer) at most ``publish_timeout_s``. While
the client is not connected (NATS down, not yet up, or reconnecting) a frame is not published and
counted as dropped, so frames are never replayed late after a reconnect; the client reconnects by
itself, forever. With ``history_s`` or ``history_msgs``, a JetStream stream (memory storage) on
the room's subject keeps that much history for a late subscriber to replay; it is created (or
updated) at each (re)connect.
"""

from __future__ import annotations

import asyncio
import logging
import re
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import TYPE_CHECKING

import msgpack

from skelfuse.fusion.engine import FusedFrame
from skelfuse.protocol.feed import frame_json
from skelfuse.server.output_osc import ROTATIONS

if TYPE_CHECKING:
    from nats.aio.client import Client

logger = logging.getLogger(__name__)

NATS_PORT = 4222
"""nats-server's default client port."""
_TOKEN = re.compile(r"[A-Za-z0-9_-]{1,64}")


def room_subject(room: str) -> str:
    """The subject a room's frames are published to: ``skelfuse.<room>.frames``.

    Raises:
        ValueError: ``room`` is not one subject token of 1..64 letters, digits, ``_`` or ``-``
            (a ``.`` would split it, ``*`` and ``>`` are wildcards).
    """
    if not _TOKEN.fullmatch(room):
        raise ValueError(f"room {room!r}: use 1..64 letters, digits, '_' or '-'")
    return f"skelfuse.{room}.frames"


def stream_name(room: str) -> str:
    """The room's JetStream stream: ``skelfuse-<room>`` (stream names may not hold ``.``)."""
    room_subject(room)
    return f"skelfuse-{room}"


@dataclass(frozen=True, slots=True)
class History:
    """JetStream retention of a room's frames: the last ``max_age_s`` seconds and, if above
    0, at most ``max_msgs`` frames (whichever is fewer)."""

    max_age_s: float = 10.0
    max_msgs: int = 0


def frame_payload(frame: FusedFrame, sent_at_s: float, rotations: bool) -> bytes:
    """``frame`` as the feed's msgpack message (``protocol/feed.py``'s ``frame_json``, with
    ``t_sent`` = ``sent_at_s``, Unix seconds; rotations when asked, no raw bodies)."""
    message = frame_json(
        frame, False, sent_at_s, orientations=ROTATIONS.of(frame) if rotations else None
    )
    packed: bytes = msgpack.packb(message, use_bin_type=True)
    return packed


class NatsSink:
    """The NATS output's sink (a :class:`~skelfuse.server.outputs.Sink`).

    ``url``: ``nats://HOST:PORT``; ``room``: the subject token (:func:`room_subject`);
    ``history``: a JetStream stream's retention, or None for core NATS only; ``clock``: Unix
    seconds, for ``t_sent``.

    Raises:
        ValueError: a bad ``room``.
    """

    def __init__(
        self,
        url: str,
        room: str,
        rotations: bool = False,
        history: History | None = None,
        clock: Callable[[], float] = time.time,
        reconnect_wait_s: float = 0.5,
        publish_timeout_s: float = 1.0,
    ) -> None:
        self.url = url
        self.subject = room_subject(room)
        self.stream = stream_name(room)
        self.rotations = rotations
        self.history = history
        self.clock = clock
        self.reconnect_wait_s = reconnect_wait_s
        self.publish_timeout_s = publish_timeout_s
        self.disconnects = 0
        self.reconnects = 0
        self._client: Client | None = None
        self._closing = False
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(
            target=self._loop.run_forever, name=f"nats-{room}", daemon=True
        )
        self._thread.start()
        self._connecting: Future[None] = asyncio.run_coroutine_threadsafe(
            self._connect(), self._loop
        )

    @property
    def connected(self) -> bool:
        """Whether the client is connected now (frames are published only then)."""
        client = self._client
        return client is not None and client.is_connected

    async def _connect(self) -> None:
        import nats

        async def on_error(exc: Exception) -> None:
            logger.debug("nats %s: %s", self.url, exc)

        async def on_disconnected() -> None:
            if self._closing:
                return
            self.disconnects += 1
            logger.warning("nats %s: disconnected; frames are dropped until it is back", self.url)

        async def on_reconnected() -> None:
            self.reconnects += 1
            logger.info("nats %s: reconnected", self.url)
            await self._ensure_stream()

        # max_reconnect_attempts=-1: retry forever, the first connection too (a server started
        # before NATS publishes once NATS is up).
        self._client = await nats.connect(
            self.url,
            allow_reconnect=True,
            max_reconnect_attempts=-1,
            reconnect_time_wait=self.reconnect_wait_s,
            connect_timeout=2,
            # Nothing buffered while disconnected: a frame published in the instant NATS goes
            # away is refused (dropped) rather than sent late after the reconnection.
            pending_size=0,
            error_cb=on_error,
            disconnected_cb=on_disconnected,
            reconnected_cb=on_reconnected,
        )
        await self._ensure_stream()

    async def _ensure_stream(self) -> None:
        """Create the room's JetStream stream, or update it to this retention (idempotent)."""
        if self.history is None or self._client is None:
            return
        from nats.js.api import DiscardPolicy, StorageType, StreamConfig
        from nats.js.errors import BadRequestError

        config = StreamConfig(
            name=self.stream,
            subjects=[self.subject],
            max_age=self.history.max_age_s,
            max_msgs=self.history.max_msgs if self.history.max_msgs > 0 else None,
            storage=StorageType.MEMORY,
            discard=DiscardPolicy.OLD,
        )
        js = self._client.jetstream()
        try:
            try:
                await js.add_stream(config)
            except BadRequestError:  # exists with another retention: take this one
                await js.update_stream(config)
        except Exception:
            logger.warning("nats %s: no JetStream stream %s", self.url, self.stream, exc_info=True)

    def send(self, frame: FusedFrame) -> int:
        """Publish one frame; 1 (dropped) when not connected (or disconnected meanwhile) or the
        publish did not finish within ``publish_timeout_s``, else 0.

        Raises:
            nats.errors.Error: the publish failed (the output counts the frame as dropped).
        """
        from nats.errors import OutboundBufferLimitError

        client = self._client
        if client is None or not client.is_connected:
            return 1
        payload = frame_payload(frame, self.clock(), self.rotations)
        future = asyncio.run_coroutine_threadsafe(client.publish(self.subject, payload), self._loop)
        try:
            future.result(self.publish_timeout_s)
        except TimeoutError:
            future.cancel()
            return 1
        except OutboundBufferLimitError:  # disconnected since the check above
            return 1
        return 0

    def close(self, timeout_s: float = 2.0) -> None:
        """Flush what was published, close the connection and stop the loop's thread."""
        self._closing = True
        self._connecting.cancel()
        client = self._client
        if client is not None and not client.is_closed:
            closing = asyncio.run_coroutine_threadsafe(client.close(), self._loop)
            try:
                closing.result(timeout_s)
            except Exception:
                logger.warning("nats %s: not closed cleanly", self.url, exc_info=True)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout_s)
        if not self._thread.is_alive():
            self._loop.close()
