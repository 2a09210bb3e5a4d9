"""The live feed conflates, from outside (issue 12, defect 2).

A real ``python -m skelfuse server`` process (bench/live/server.py: loopback, stored
calibration, uvicorn as ``skelfuse server`` runs it) fed by the load benchmark's fake agents (a
child process of real ZeroMQ agents at 30 fps), and three real clients at once:

- a healthy ``websockets`` client that reads every frame: it must get every ``seq``;
- a slow reader: a raw TCP WebSocket client (default socket buffers) that reads one message
  every 0.2 s, answering pings as RFC 6455 requires: once settled, the frames it gets must be
  at most 100 ms old (receive time minus ``t_sent``, the server's publish time);
- a client that completes the handshake and then never reads (its kernel buffers fill): it
  must be closed with 1008 and counted as evicted 5 s after its last frame (docs/api.md), not
  cut by the keepalive (1011, about 10 s) as before.

The server's RSS must grow by less than 20 MB meanwhile. Before this fix the slow reader's
frames were seconds old and growing, and ``evicted`` stayed 0.
"""

from __future__ import annotations

import asyncio
import base64
import itertools
import multiprocessing as mp
import os
import signal
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson
import pytest
from websockets.asyncio.client import connect

from bench.live.agents import agents_process, sensor_layout
from bench.live.server import free_port, http_json, proc_rss_mb, start_server, wait_for

pytestmark = pytest.mark.timeout(150)

EVICT_AFTER_S = 5.0  # docs/api.md, Settings.ws_send_timeout_s
SETTLE_READS = 15  # frames the slow reader may find queued before it is paced (3 s at 5/s)


class RawWebSocket:
    """A WebSocket client on a plain socket: it reads exactly when the test says so."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET /ws/skeletons HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                "Upgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:  # byte by byte: nothing after the handshake is read
            chunk = self.sock.recv(1)
            assert chunk, "the server closed the handshake"
            head += chunk
        assert b" 101 " in head.split(b"\r\n", 1)[0], head[:80]
        self.local_port: int = self.sock.getsockname()[1]

    def _exactly(self, count: int) -> bytes:
        data = bytearray()
        while len(data) < count:
            chunk = self.sock.recv(count - len(data))
            if not chunk:
                raise EOFError("connection closed")
            data += chunk
        return bytes(data)

    def read_message(self) -> tuple[int, bytes]:
        """The next data or close message (opcode, payload); pings are answered on the way."""
        while True:
            first, second = self._exactly(2)
            length = second & 0x7F
            if length == 126:
                length = struct.unpack("!H", self._exactly(2))[0]
            elif length == 127:
                length = struct.unpack("!Q", self._exactly(8))[0]
            payload = self._exactly(length)
            opcode = first & 0x0F
            if opcode == 0x9:  # ping: a masked pong with the same payload (zero mask)
                self.sock.sendall(bytes([0x8A, 0x80 | len(payload)]) + bytes(4) + payload)
                continue
            if opcode != 0xA:
                return opcode, payload

    def close_code(self) -> int | None:
        """Read everything left until the server's close message; its code (None: no close)."""
        try:
            while True:
                opcode, payload = self.read_message()
                if opcode == 0x8:
                    return int(struct.unpack("!H", payload[:2])[0]) if payload else None
        except (EOFError, OSError):
            return None


@pytest.fixture
def feed_server(tmp_path: Path) -> Iterator[tuple[str, int, int]]:
    """The server process with two fake agents seeing two people: (http base, port, pid)."""
    http_port, zmq_port = free_port(), free_port()
    poses = sensor_layout(2)
    server, log = start_server(poses, http_port, zmq_port, tmp_path / "server.log")
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    results: mp.Queue[Any] = ctx.Queue()
    agents = ctx.Process(
        target=agents_process,
        args=(
            f"tcp://127.0.0.1:{zmq_port}",
            {s: [float(x) for x in p.reshape(16)] for s, p in poses.items()},
            2, 1, 120.0, stop, results,
        ),
        daemon=True,
    )  # fmt: skip
    base = f"http://127.0.0.1:{http_port}"
    try:
        wait_for(lambda: http_json(base + "/api/health"), 30, "the server to start")
        agents.start()
        wait_for(lambda: http_json(base + "/api/health")["fused_frames"] > 30, 30, "fusion")
        yield base, http_port, server.pid
    finally:
        stop.set()
        if agents.is_alive() or agents.pid is not None:
            agents.join(5)
            if agents.is_alive():
                agents.kill()
        server.send_signal(signal.SIGINT)
        try:
            server.wait(15)
        except Exception:
            server.kill()
        log.close()


def _slow_reader(port: int, reads: int, ages: list[float], failure: list[str]) -> None:
    """Read one frame every 0.2 s; the age of each (receive time minus ``t_sent``)."""
    try:
        client = RawWebSocket(port)
        client.read_message()  # the skeleton definition
        for _ in range(reads):
            opcode, payload = client.read_message()
            assert opcode == 0x1, f"opcode {opcode}: {payload[:40]!r}"
            ages.append(time.time() - orjson.loads(payload)["t_sent"])
            time.sleep(0.2)
        client.sock.close()
    except Exception as exc:  # reported by the test
        failure.append(f"{type(exc).__name__}: {exc}")


async def test_slow_readers_get_the_newest_frame_and_a_stalled_one_is_evicted(
    feed_server: tuple[str, int, int],
) -> None:
    base, port, pid = feed_server
    rss_start = proc_rss_mb(pid)
    ages: list[float] = []
    failure: list[str] = []
    slow = threading.Thread(target=_slow_reader, args=(port, 45, ages, failure), daemon=True)
    stalled = await asyncio.to_thread(RawWebSocket, port)
    connected = time.monotonic()
    slow.start()
    seqs: list[int] = []
    async with connect(f"ws://127.0.0.1:{port}/ws/skeletons", compression=None) as healthy:
        await healthy.recv()
        evicted_after: float | None = None
        polled = 0.0
        while slow.is_alive() or evicted_after is None:
            assert time.monotonic() - connected < 40, "the stalled client was never evicted"
            try:
                message = await asyncio.wait_for(healthy.recv(), 0.5)
                seqs.append(orjson.loads(message)["seq"])
            except TimeoutError:
                pass
            if evicted_after is None and time.monotonic() - polled > 0.2:
                polled = time.monotonic()
                clients = await asyncio.to_thread(http_json, base + "/api/clients")
                ports = [str(c["remote"]) for c in clients["clients"]]
                if not any(r.endswith(f"port={stalled.local_port})") for r in ports):
                    evicted_after = time.monotonic() - connected
                    assert clients["evicted"] == 1
    rss_growth = proc_rss_mb(pid) - rss_start
    code = await asyncio.to_thread(stalled.close_code)
    stalled.sock.close()
    assert not failure, failure
    assert code == 1008, f"the stalled client got close code {code}, not 1008"
    assert evicted_after is not None and EVICT_AFTER_S <= evicted_after <= EVICT_AFTER_S + 2.0
    settled = sorted(ages[SETTLE_READS:])
    assert settled[int(0.9 * len(settled))] <= 0.1, f"slow reader's ages (s): {ages}"
    assert settled[-1] < 0.5, f"slow reader's ages (s): {ages}"
    gaps = [b - a for a, b in itertools.pairwise(seqs) if b != a + 1]
    assert len(seqs) > 200 and not gaps, f"the healthy client lost frames: {gaps}"
    assert rss_growth < 20.0, f"server RSS grew {rss_growth:.1f} MB"
