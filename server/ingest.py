"""ZeroMQ side of the server: the ROUTER socket, the liveness timer and the fusion loop.

One task owns the socket (receiving and replying); nothing else touches it. A message that
fails validation is counted against its sensor and dropped; the loop never dies of bad input.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zmq
import zmq.asyncio
from zmq.utils.monitor import parse_monitor_message

from skelfuse.protocol.constants import MAX_RESPONSE_BYTES
from skelfuse.protocol.wire import Heartbeat, Message, encode
from skelfuse.server.auth import secure_router
from skelfuse.server.hub import FusionHub
from skelfuse.server.outputs import FramePublisher
from skelfuse.server.stage_timing import StageTimes

logger = logging.getLogger(__name__)

# Messages past the protocol's limits are still received, refused and counted (too_large) up to
# this size: it must stay above the largest answer the protocol allows (MAX_RESPONSE_BYTES), with
# room for a too-large one to be refused by the hub rather than cut by libzmq. Only beyond it
# does libzmq drop the connection, which the agent then re-opens.
SOCKET_MAX_MESSAGE_BYTES = 2 * MAX_RESPONSE_BYTES


def open_router(
    context: zmq.asyncio.Context, endpoint: str, curve_data_dir: Path | None = None
) -> zmq.asyncio.Socket:
    """Bind the agents' ROUTER socket; with ``curve_data_dir``, only CurveZMQ-authenticated
    agents can connect (docs/security.md)."""
    socket = context.socket(zmq.ROUTER)
    if curve_data_dir is not None:
        secure_router(socket, curve_data_dir)
    socket.linger = 0
    socket.rcvhwm = 10_000
    socket.sndhwm = 1_000
    socket.setsockopt(zmq.MAXMSGSIZE, SOCKET_MAX_MESSAGE_BYTES)
    socket.setsockopt(zmq.ROUTER_HANDOVER, 1)  # a reconnecting agent may reuse its identity
    # Sending to a connection that is gone fails at once (EHOSTUNREACH) instead of vanishing:
    # that is how connection_probe tells a crashed agent from a live one.
    socket.setsockopt(zmq.ROUTER_MANDATORY, 1)
    try:
        socket.bind(endpoint)
    except zmq.ZMQError as exc:
        socket.close(linger=0)
        raise OSError(f"cannot bind the agent endpoint {endpoint}: {exc}") from exc
    return socket


async def send_to(socket: zmq.asyncio.Socket, routing_id: bytes, message: Message) -> None:
    with contextlib.suppress(zmq.Again, zmq.ZMQError):
        # ROUTER drops what it cannot route; never let one agent block the loop.
        await socket.send_multipart([routing_id, encode(message)], flags=zmq.NOBLOCK)


def connection_probe(socket: zmq.asyncio.Socket) -> Callable[[bytes], bool]:
    """Whether the connection with a routing id is still open, for the hub's registration rule
    (``skelfuse.server.registration``). It sends that connection a heartbeat (agents answer
    any heartbeat with an echo); with ``ROUTER_MANDATORY`` a closed one refuses it at once."""
    raw: zmq.Socket[bytes] = zmq.Socket.shadow(socket.underlying)

    def probe(routing_id: bytes) -> bool:
        # Reading EVENTS makes libzmq apply the commands its I/O thread left for the socket,
        # such as "this connection closed" (a send applies them at most once a millisecond).
        raw.getsockopt(zmq.EVENTS)
        try:
            raw.send_multipart([routing_id, encode(Heartbeat(time.time_ns()))], zmq.NOBLOCK)
        except zmq.Again:
            return True  # open, its queue full
        except zmq.ZMQError as exc:
            return exc.errno != zmq.EHOSTUNREACH
        return True

    return probe


INGEST_SLICE_S = 0.005
"""While messages keep coming, the ingest loop hands the event loop back at least this often,
so the fusion loop and the web server keep their rate under a flood of messages."""


async def ingest_loop(
    socket: zmq.asyncio.Socket,
    hub: FusionHub,
    authenticated: bool,
    stages: StageTimes | None = None,
) -> None:
    """Receive and handle every agent message; ``stages`` (optional) times each one.

    Messages already queued are drained through a synchronous view of the same socket (no
    future per message) in slices of at most :data:`INGEST_SLICE_S`, with the event loop's turn
    between slices: awaiting a message that is already there does not yield, so a burst of
    12,000 would otherwise hold every other task until its last one.
    """
    stages = StageTimes() if stages is None else stages
    hub.attach_probe(connection_probe(socket))
    queued: zmq.Socket[bytes] = zmq.Socket.shadow(socket.underlying)
    handshakes = asyncio.create_task(handshake_monitor_loop(socket, hub), name="handshakes")
    try:
        while True:
            await socket.poll()  # until a message is there
            slice_end = time.perf_counter() + INGEST_SLICE_S
            while time.perf_counter() < slice_end:
                try:
                    # Bytes are cheaper than Frame objects; only a Frame knows its User-Id.
                    frames: list[Any] = queued.recv_multipart(zmq.NOBLOCK, copy=not authenticated)
                except zmq.Again:
                    break
                await _handle(socket, hub, frames, authenticated, stages)
            await asyncio.sleep(0)
    finally:
        # Awaited, not just cancelled: its monitor socket must be closed before the context
        # is terminated, or the termination waits forever.
        handshakes.cancel()
        await asyncio.gather(handshakes, return_exceptions=True)


HANDSHAKE_WARNING_EVERY_S = 60.0
_HANDSHAKE_ADVICE = {
    "handshake_no_key": "an agent without a CurveZMQ key was refused: this server runs with "
    "--curve, so each agent needs --key <sensor id>.key_secret and --server-key server.key "
    "(made by 'skelfuse keys create'; docs/security.md)",
    "handshake_key_refused": "an agent with a CurveZMQ key that is not allowlisted was refused "
    "(keys/agents/<sensor id>.key; restart the server after adding one)",
    "handshake_protocol": "a ZeroMQ handshake failed (a peer that is not a skelfuse agent, or "
    "an agent with keys against a server without --curve)",
    # What a CurveZMQ server usually sees of an agent without a key: the agent notices the
    # mechanism mismatch first and hangs up, so the server's side has no detail.
    "handshake_failed": "a connection was closed during the ZeroMQ handshake: with --curve, "
    "most likely an agent without a CurveZMQ key (it needs --key <sensor id>.key_secret and "
    "--server-key server.key; docs/security.md)",
}


def handshake_failure(event: int, value: int) -> str:
    """The ``rejected_unregistered`` reason of a failed handshake (a monitor event)."""
    if event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
        return "handshake_key_refused"
    if event == zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL:
        return "handshake_failed"
    if value == zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH:
        return "handshake_no_key"
    return "handshake_protocol"


async def handshake_monitor_loop(socket: zmq.asyncio.Socket, hub: FusionHub) -> None:
    """Count the connections the ZeroMQ handshake turned away (with CurveZMQ: an agent with no
    key, or a key not allowlisted) in ``hub.rejected_unregistered``, and say why in the log
    (per cause at most every :data:`HANDSHAKE_WARNING_EVERY_S`). They never reach the ingest
    loop, so nothing else would see them; the handshake itself is libzmq's, unchanged."""
    monitor = socket.get_monitor_socket(
        zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
        | zmq.EVENT_HANDSHAKE_FAILED_AUTH
        | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
    )
    warned: dict[str, float] = {}
    try:
        while True:
            event = parse_monitor_message(await monitor.recv_multipart())
            reason = handshake_failure(int(event["event"]), int(event["value"]))
            hub.rejected_unregistered[reason] += 1
            now = time.monotonic()
            if now - warned.get(reason, -HANDSHAKE_WARNING_EVERY_S) >= HANDSHAKE_WARNING_EVERY_S:
                warned[reason] = now
                logger.warning("%s (counted as %s)", _HANDSHAKE_ADVICE[reason], reason)
    finally:
        with contextlib.suppress(zmq.ZMQError):
            socket.disable_monitor()
        monitor.close(linger=0)


async def _handle(
    socket: zmq.asyncio.Socket,
    hub: FusionHub,
    frames: list[Any],
    authenticated: bool,
    stages: StageTimes,
) -> None:
    user_id = None
    if authenticated:  # Frames: the ZAP handler names the sensor this connection's key is for
        user_id = frames[1].get("User-Id") if len(frames) > 1 else None
        frames = [frame.bytes for frame in frames]
    routing_id, payload = frames[0], frames[1:]
    started = time.perf_counter()
    try:
        replies = hub.handle_message(
            routing_id, payload, time.time(), time.monotonic(), user_id=user_id
        )
        stages.ingest.record(time.perf_counter() - started)
    except Exception:  # a bug in handling one message must not stop ingest
        logger.exception("failed to handle a message; dropped")
        hub.rejected_unregistered["internal_error"] += 1
        return
    for reply in replies:
        await send_to(socket, routing_id, reply)


async def liveness_loop(socket: zmq.asyncio.Socket, hub: FusionHub, interval_s: float) -> None:
    """Mark silent agents offline (checked every 0.2 s) and heartbeat live ones twice per
    interval (each echo is a round-trip clock sample)."""
    last_heartbeat = 0.0
    while True:
        await asyncio.sleep(0.2)
        online = hub.check_liveness(time.monotonic())
        if time.monotonic() - last_heartbeat >= interval_s / 2:
            last_heartbeat = time.monotonic()
            for sensor in online:
                await send_to(socket, sensor.routing_id, Heartbeat(time.time_ns()))


IDLE_WAKE_S = 0.05
"""The fusion loop wakes at least this often (seconds), frames or not."""


def wake_in_s(hub: FusionHub, now_s: float) -> float:
    """How long the fusion loop may sleep before the next fusion step (seconds): until a frame
    arrives, or at most until the pending instant's deadline (``alignment = "deadline"``: a
    timer, so a late sensor delays the instant only until then), or :data:`IDLE_WAKE_S`."""
    due = hub.alignment.due_s
    if due is None:
        return IDLE_WAKE_S
    return min(IDLE_WAKE_S, max(0.0, due - now_s))


async def fusion_loop(
    hub: FusionHub, broadcaster: FramePublisher, stages: StageTimes | None = None
) -> None:
    """Fuse each instant when the alignment policy says it is due (every live sensor has moved
    on, or its deadline passed); publish to WebSocket clients (and the outputs: a Fanout).
    ``stages`` (optional) times each fusion step that produced a frame, and its publishing."""
    stages = StageTimes() if stages is None else stages
    while True:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(hub.frame_arrived.wait(), timeout=wake_in_s(hub, time.time()))
        hub.frame_arrived.clear()
        started = time.perf_counter()
        try:
            fused = hub.fuse_step(time.time())
        except Exception:
            logger.exception("fusion step failed; skipped")
            continue
        if fused is not None:
            published = time.perf_counter()
            broadcaster.publish(fused, time.time(), time.monotonic())
            stages.fusion.record(published - started)
            stages.publish.record(time.perf_counter() - published)
            stages.lag.record(fused.fused_at_s - fused.t_s)
