"""The agent's connection to the fusion server: a ZeroMQ DEALER with heartbeats.

Synchronous sockets in the capture thread on purpose: Windows sensor PCs run a Proactor event
loop that pyzmq's asyncio support handles poorly (``shared/conventions.md`` §4).

Rules (``docs/protocol.md``):

- Register with ``hello``; frames are sent only while registered, and never queued beyond
  :data:`~protocol.constants.AGENT_SEND_HWM` (IMMEDIATE=1, small HWM, non-blocking sends), so a
  server outage never turns into a stale backlog: frames that cannot go out are dropped and
  counted.
- Silence from the server for ``HEARTBEAT_LIVENESS`` intervals, or an ``error`` with code
  ``not_registered`` (the server restarted), sends us back to registering.
- A moving sensor (``hello.moving``) streams only to a server whose ``welcome`` lists
  :data:`MOVING_SENSORS` in ``features``: any other server would fuse its frames as if the sensor
  stood still. Otherwise it stays registered (heartbeats, requests) but sends no frame, says why
  once in the log and counts the frames in ``frames_refused``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zmq
import zmq.auth

from skelfuse.agent.handshake import HandshakeWatch
from skelfuse.protocol.constants import (
    AGENT_SEND_HWM,
    HEARTBEAT_INTERVAL_S,
    HEARTBEAT_LIVENESS,
    MAX_RESPONSE_BYTES,
    MOVING_SENSORS,
)
from skelfuse.protocol.errors import DecodeError
from skelfuse.protocol.wire import (
    Bye,
    ErrorMessage,
    Frame,
    Heartbeat,
    Hello,
    Message,
    Request,
    Response,
    Welcome,
    decode,
    encode,
)

logger = logging.getLogger(__name__)

RequestHandler = Callable[[dict[str, Any]], Any]


@dataclass(frozen=True, slots=True)
class CurveKeys:
    """This agent's key pair file and the server's public key file (docs/security.md)."""

    agent_secret_file: Path
    server_public_file: Path

    def apply(self, socket: zmq.Socket[Any]) -> None:
        for path in (self.agent_secret_file, self.server_public_file):
            if not path.is_file():
                raise FileNotFoundError(f"key file {path} not found (see 'skelfuse keys')")
        public, secret = zmq.auth.load_certificate(self.agent_secret_file)
        if secret is None:
            raise ValueError(f"{self.agent_secret_file} holds no secret key: pass the .key_secret")
        server_public, _ = zmq.auth.load_certificate(self.server_public_file)
        socket.curve_publickey = public
        socket.curve_secretkey = secret
        socket.curve_serverkey = server_public


@dataclass(slots=True)
class LinkStats:
    frames_sent: int = 0
    frames_dropped: int = 0
    frames_refused: int = 0
    registrations: int = 0
    server_errors: dict[str, int] = field(default_factory=dict)


class AgentLink:
    """Owns one DEALER socket; call :meth:`poll` often and :meth:`send_frame` per capture."""

    def __init__(
        self,
        endpoint: str,
        hello: Callable[[], Hello],
        *,
        context: zmq.Context[Any] | None = None,
        heartbeat_interval_s: float = HEARTBEAT_INTERVAL_S,
        liveness: int = HEARTBEAT_LIVENESS,
        handlers: dict[str, RequestHandler] | None = None,
        clock: Callable[[], float] = time.monotonic,
        curve: CurveKeys | None = None,
        wall_clock_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        self._endpoint = endpoint
        self._make_hello = hello
        self._own_context = context is None
        self._context = context or zmq.Context()
        self._interval = heartbeat_interval_s
        self._liveness = liveness
        self._handlers = handlers or {}
        self._clock = clock
        self._curve = curve
        self._wall_clock_ns = wall_clock_ns
        self._workers = ThreadPoolExecutor(max_workers=1, thread_name_prefix="agent-request")
        self._running: list[tuple[Request, Future[Any]]] = []
        self.stats = LinkStats()
        self.registered = False
        self.refusal: str | None = None
        """Why frames are not sent to this server (a moving sensor, a server without
        :data:`MOVING_SENSORS`), or None."""
        self._moving = False
        self._last_heard = -float("inf")
        self._last_sent = -float("inf")
        self._last_hello = -float("inf")
        self._socket = self._open()
        self._poller: zmq.Poller | None = None
        self._poller_fd = -1
        self.handshake = HandshakeWatch(self._socket, endpoint, curve is not None, clock)
        """Failed handshakes (a key missing or refused), said in the log and counted."""

    def _open(self) -> zmq.Socket[Any]:
        socket = self._context.socket(zmq.DEALER)
        if self._curve is not None:
            self._curve.apply(socket)
        socket.linger = 0
        socket.sndhwm = AGENT_SEND_HWM
        socket.rcvhwm = 100
        socket.setsockopt(zmq.IMMEDIATE, 1)
        socket.setsockopt(zmq.RECONNECT_IVL, 100)
        socket.setsockopt(zmq.RECONNECT_IVL_MAX, 2000)
        socket.connect(self._endpoint)
        return socket

    # --- sending ---------------------------------------------------------------------------

    def _send(self, message: Message) -> bool:
        try:
            self._socket.send(encode(message), zmq.NOBLOCK)
        except zmq.Again:
            return False
        self._last_sent = self._clock()
        return True

    def send_frame(self, frame: Frame) -> bool:
        """Send one frame now or drop it (never blocks, never queues a backlog).

        A frame is refused (``frames_refused``) while :attr:`refusal` says why, and dropped
        (``frames_dropped``) while unregistered or when the send queue is full.
        """
        if self.refusal is not None:
            self.stats.frames_refused += 1
            return False
        if not self.registered or not self._send(frame):
            self.stats.frames_dropped += 1
            return False
        self.stats.frames_sent += 1
        return True

    # --- receiving and timers ----------------------------------------------------------------

    @property
    def socket(self) -> zmq.Socket[Any]:
        """The link's socket, to wait on it with others (``zmq.Poller``); only :meth:`poll`
        reads it, in the thread that calls :meth:`poll` and :meth:`send_frame`."""
        return self._socket

    def poll(self, timeout_s: float = 0.0, wake_fd: int | None = None) -> None:
        """Handle everything the server sent, then heartbeats and re-registration.

        Waits up to ``timeout_s`` for the server, or until ``wake_fd`` (a file descriptor, such
        as :meth:`skelfuse.agent.capture_thread.CaptureThread.fileno`) is readable; the caller
        reads ``wake_fd``. A heartbeat is answered as soon as it is read: the echo's stamp is
        the server's measure of this agent's clock (docs/fusion.md §1).
        """
        deadline_ms = int(timeout_s * 1000)
        if wake_fd is not None and deadline_ms > 0:
            if self._poller is None or self._poller_fd != wake_fd:
                self._poller = zmq.Poller()
                self._poller.register(self._socket, zmq.POLLIN)
                self._poller.register(wake_fd, zmq.POLLIN)
                self._poller_fd = wake_fd
            self._poller.poll(deadline_ms)
            deadline_ms = 0
        while self._socket.poll(deadline_ms, zmq.POLLIN):
            deadline_ms = 0
            self._handle(self._socket.recv())
        self._finish_requests()
        self.handshake.poll(self.registered)
        now = self._clock()
        if self.registered and now - self._last_heard > self._interval * self._liveness:
            logger.warning("server silent for %.1f s; registering again", now - self._last_heard)
            self.registered = False
        if not self.registered and now - self._last_hello >= self._interval:
            self._last_hello = now
            hello = self._make_hello()
            self._moving = hello.moving
            self._send(hello)
        elif self.registered and now - self._last_sent >= self._interval:
            self._send(Heartbeat(t_ns=self._wall_clock_ns()))

    def _handle(self, payload: bytes) -> None:
        try:
            message = decode(payload)
        except DecodeError as exc:
            logger.warning("dropped a malformed message from the server: %s", exc)
            return
        self._last_heard = self._clock()
        match message:
            case Welcome():
                if not self.registered:
                    self.stats.registrations += 1
                    logger.info(
                        "registered with server %s (%s)", self._endpoint, message.server_version
                    )
                self.registered = True
                self._check_features(message)
            case ErrorMessage(code=code):
                self.stats.server_errors[code] = self.stats.server_errors.get(code, 0) + 1
                if code == "not_registered":
                    self.registered = False
                    self._last_hello = -float("inf")
                else:
                    logger.warning("server refused a message: %s: %s", code, message.message)
            case Request():
                self._start(message)
            case Heartbeat(echo_ns=None):
                # Answer at once with the server's stamp: it measures round trip and offset.
                self._send(Heartbeat(t_ns=self._wall_clock_ns(), echo_ns=message.t_ns))
            case Heartbeat():
                pass
            case _:
                logger.debug("ignored unexpected %s from server", type(message).__name__)

    def _check_features(self, welcome: Welcome) -> None:
        """Refuse to stream a moving sensor to a server that would treat it as fixed."""
        if not self._moving or MOVING_SENSORS in welcome.features:
            if self.refusal is not None:
                logger.info("server %s now handles moving sensors: streaming", self._endpoint)
            self.refusal = None
            return
        if self.refusal is None:
            self.refusal = (
                f"this sensor is configured as moving but the server at {self._endpoint} "
                f"({welcome.server_version}) does not announce {MOVING_SENSORS!r} in its "
                "welcome: it would fuse the frames as if the sensor stood still, so none are "
                "sent (upgrade the server, or run the sensor as fixed; docs/protocol.md §6.2)"
            )
            logger.error("%s", self.refusal)

    def _start(self, request: Request) -> None:
        """Run a request's handler in a worker thread: a depth capture can take a second under
        load, and the capture loop must keep streaming and heartbeating meanwhile."""
        handler = self._handlers.get(request.method)
        if handler is None:
            self._send(
                Response(
                    request.request_id,
                    ok=False,
                    error=f"method {request.method!r} not supported by this agent",
                )
            )
            return
        self._running.append((request, self._workers.submit(handler, request.params)))

    def _finish_requests(self) -> None:
        """Send the answers of finished requests (from the capture thread, which owns the
        socket)."""
        still_running = []
        for request, future in self._running:
            if not future.done():
                still_running.append((request, future))
                continue
            exc = future.exception()
            if exc is None:
                response = Response(request.request_id, ok=True, result=future.result())
            else:  # a failing handler must not kill the capture loop
                logger.error("request %s failed: %s", request.method, exc)
                response = Response(
                    request.request_id, ok=False, error=f"{type(exc).__name__}: {exc}"
                )
            size = len(encode(response))
            if size > MAX_RESPONSE_BYTES:  # the server would refuse it: say why instead
                logger.error(
                    "the answer to %s is %d bytes, over the %d-byte limit; sent an error instead",
                    request.method,
                    size,
                    MAX_RESPONSE_BYTES,
                )
                response = Response(
                    request.request_id,
                    ok=False,
                    error=f"the answer is {size} bytes, over the protocol's limit of "
                    f"{MAX_RESPONSE_BYTES} bytes for answers",
                )
            if not self._send(response):
                logger.warning("could not send the answer to %s; dropped", request.method)
        self._running = still_running

    def close(self) -> None:
        """Say goodbye (best effort) and release the socket."""
        self._workers.shutdown(wait=False, cancel_futures=True)
        self.handshake.close()
        said_bye = self.registered and self._send(Bye())
        # A short linger lets the bye leave; nothing else can be queued (frames are dropped).
        self._socket.close(linger=200 if said_bye else 0)
        if self._own_context:
            self._context.term()
