"""The load benchmark's WebSocket clients: healthy readers that log every frame, one that
completes the handshake and then never reads, and a raw reader that does the least work a
client can per message (``python -m bench many_clients --client raw``)."""

from __future__ import annotations

import asyncio
import json
import re
import socket
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast


@dataclass
class ClientLog:
    """One healthy client's frames (receive wall time s, seq, t s, t_sent s) and why it stopped."""

    records: list[tuple[float, int, float, float]] = field(default_factory=list)
    error: str | None = None


async def healthy_client(url: str, log: ClientLog) -> None:
    """Log every frame from ``url`` until cancelled; a failure goes in ``log.error``."""
    from websockets.asyncio.client import connect

    try:
        async with connect(url, max_size=2**22) as ws:
            await ws.recv()  # the skeleton definition
            async for message in ws:
                received = time.time()
                data = json.loads(message)
                if data.get("type") == "frame":
                    log.records.append((received, data["seq"], data["t"], data["t_sent"]))
    except asyncio.CancelledError:
        raise
    except Exception as exc:
        log.error = f"{type(exc).__name__}: {exc}"


async def raw_healthy_client(url: str, log: ClientLog) -> None:
    """As :func:`healthy_client` on a :class:`RawFeedReader`: each frame is timed when its bytes
    reach the client process, and only its head (seq, t, t_sent) is read; the JSON parse a real
    app does is its own cost, which 20 clients in one process would otherwise pay one after
    another before the last one's receive time is read (``python -m bench load --client raw``)."""
    host_port, path = url.removeprefix("ws://").split("/", 1)
    host, port = host_port.rsplit(":", 1)

    def on_message(head: bytes, received: float) -> None:
        match = HEAD_BYTES.search(head)
        if match is not None:
            seq, t, t_sent = match.groups()
            log.records.append((received, int(seq), float(t), float(t_sent)))

    reader = RawFeedReader("/" + path, host, int(port), on_message)
    loop = asyncio.get_running_loop()
    transport: asyncio.BaseTransport | None = None
    try:
        transport, _ = await loop.create_connection(_factory(reader), host, int(port))
        await reader.done.wait()
        log.error = reader.error or "closed by the server"
    except asyncio.CancelledError:
        raise
    except Exception as exc:
        log.error = f"{type(exc).__name__}: {exc}"
    finally:
        if transport is not None:
            transport.close()


def open_stalled_client(port: int) -> tuple[socket.socket, int]:
    """A WebSocket client that completes the handshake and then never reads again."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # no autotuning: stalls fast
    sock.connect(("127.0.0.1", port))
    sock.sendall(
        (
            "GET /ws/skeletons HTTP/1.1\r\n"
            f"Host: 127.0.0.1:{port}\r\n"
            "Upgrade: websocket\r\nConnection: Upgrade\r\n"
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    sock.settimeout(5)
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = sock.recv(1)  # byte by byte: read the handshake answer and nothing more
        if not chunk:
            raise RuntimeError("the server closed the stalled client's handshake")
        head += chunk
    if b" 101 " not in head.split(b"\r\n", 1)[0]:
        raise RuntimeError(f"stalled client's handshake failed: {head[:80]!r}")
    local_port: int = sock.getsockname()[1]
    return sock, local_port


HANDSHAKE = (
    "GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
)


class RawFeedReader(asyncio.Protocol):
    """A WebSocket feed client with as little work per message as a client can do: the frames
    parsed from the byte stream, pings answered (the server paces clients by them), and each
    data message's first ``head_bytes`` handed to ``on_message(head, received_s)``, nothing else
    (no UTF-8 check, no message object). For measuring the server with many clients on the same
    machine, where a full client library's cost per message is the clients' own share of what
    they measure.

    ``done`` is set when the connection ends; ``error`` says why, if not by a close.
    """

    def __init__(
        self,
        path: str,
        host: str,
        port: int,
        on_message: Callable[[bytes, float], None],
        head_bytes: int = 200,
    ) -> None:
        self.request = HANDSHAKE.format(path=path, host=host, port=port).encode()
        self.on_message = on_message
        self.head_bytes = head_bytes
        self.buffer = bytearray()
        self.upgraded = False
        self.transport: asyncio.Transport | None = None
        self.done = asyncio.Event()
        self.error: str | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        self.transport.write(self.request)

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None and self.error is None:
            self.error = f"{type(exc).__name__}: {exc}"
        self.done.set()

    def data_received(self, data: bytes) -> None:
        received = time.time()
        buffer = self.buffer
        buffer += data
        start = 0
        if not self.upgraded:
            end = buffer.find(b"\r\n\r\n")
            if end < 0:
                return
            if b" 101 " not in buffer[: buffer.find(b"\r\n")]:
                self.error = f"handshake refused: {bytes(buffer[:60])!r}"
                self._close()
                return
            self.upgraded = True
            start = end + 4
        size = len(buffer)
        while size - start >= 2:
            opcode = buffer[start] & 0x0F
            length = buffer[start + 1] & 0x7F
            offset = start + 2
            if length == 126:
                if size - offset < 2:
                    break
                length = int.from_bytes(buffer[offset : offset + 2], "big")
                offset += 2
            elif length == 127:
                if size - offset < 8:
                    break
                length = int.from_bytes(buffer[offset : offset + 8], "big")
                offset += 8
            if size - offset < length:
                break
            if opcode in (1, 2):
                self.on_message(
                    bytes(buffer[offset : offset + min(length, self.head_bytes)]), received
                )
            elif opcode == 9 and self.transport is not None:  # ping: a pong, masked by zeros
                payload = bytes(buffer[offset : offset + length])
                self.transport.write(bytes([0x8A, 0x80 | length]) + bytes(4) + payload)
            elif opcode == 8:
                self._close()
                return
            start = offset + length
        del buffer[:start]

    def _close(self) -> None:
        if self.transport is not None:
            self.transport.close()


HEAD_BYTES = re.compile(rb'"seq":(\d+),"t":([0-9.eE+-]+),"t_sent":([0-9.eE+-]+)')


class FeedTally:
    """One viewer's counts, as ``bench/live/many_clients.py`` reports them: frames, ``seq`` gaps,
    connection errors and retries, and ages (receive time minus ``t`` and ``t_sent``, seconds)."""

    def __init__(self) -> None:
        self.out: dict[str, Any] = {"frames": 0, "lost": 0, "error": None, "retries": 0}
        self.ages_sent, self.ages_t = array("d"), array("d")
        self.last_seq = -1

    def count(self, head: re.Match[str] | re.Match[bytes], received: float) -> None:
        """Count one frame whose head (``HEAD``'s groups: seq, t, t_sent) arrived at
        ``received`` (epoch seconds)."""
        seq = int(head.group(1))
        if self.last_seq >= 0 and seq > self.last_seq + 1:
            self.out["lost"] += seq - self.last_seq - 1
        self.last_seq = seq
        self.out["frames"] += 1
        self.ages_t.append(received - float(head.group(2)))
        self.ages_sent.append(received - float(head.group(3)))

    def result(self) -> dict[str, Any]:
        """The counts, with the ages as float64 bytes (``ages_sent``, ``ages_t``)."""
        self.out["ages_sent"], self.out["ages_t"] = self.ages_sent.tobytes(), self.ages_t.tobytes()
        return self.out


def _factory(reader: RawFeedReader) -> Callable[[], RawFeedReader]:
    return lambda: reader


async def raw_client(url: str, measuring: asyncio.Event, stopping: asyncio.Event) -> dict[str, Any]:
    """One viewer of ``bench/live/many_clients.py`` on a :class:`RawFeedReader`: frames, ``seq``
    gaps and ages (receive time minus ``t`` and ``t_sent``) counted while ``measuring`` and not
    ``stopping``, as its ``websockets`` client counts them, for a fraction of the CPU."""
    tally = FeedTally()
    out = tally.out

    def on_message(head: bytes, received: float) -> None:
        match = HEAD_BYTES.search(head)
        if match is not None and measuring.is_set():
            tally.count(match, received)

    host_port, path = url.removeprefix("ws://").split("/", 1)
    host, port = host_port.rsplit(":", 1)
    loop = asyncio.get_running_loop()
    while not stopping.is_set():
        reader = RawFeedReader("/" + path, host, int(port), on_message)
        try:
            transport, _ = await asyncio.wait_for(
                loop.create_connection(_factory(reader), host, int(port)), 30
            )
        except (OSError, TimeoutError) as exc:
            out["error"] = f"{type(exc).__name__}: {exc}"
            if measuring.is_set():
                break
            out["retries"] += 1
            await asyncio.sleep(1.0)
            continue
        stop_task = asyncio.create_task(stopping.wait())
        done_task = asyncio.create_task(reader.done.wait())
        await asyncio.wait({stop_task, done_task}, return_when=asyncio.FIRST_COMPLETED)
        stop_task.cancel()
        done_task.cancel()
        transport.close()
        if not stopping.is_set():
            out["error"] = reader.error or "closed by the server"
            if measuring.is_set() or out["frames"]:
                break
            out["retries"] += 1
            await asyncio.sleep(1.0)
    return tally.result()
