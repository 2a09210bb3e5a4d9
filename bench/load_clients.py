"""The load benchmark's WebSocket clients: healthy readers that log every frame, and one that
completes the handshake and then never reads."""

from __future__ import annotations

import asyncio
import json
import socket
import time
from dataclasses import dataclass, field


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
