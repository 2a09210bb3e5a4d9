"""A burst of malformed agent messages from one peer must not freeze the live feed (issue 12 #10).

Starts ``skelfuse server`` and one ``skelfuse agent`` (sim, 30 fps) as processes on loopback,
reads the WebSocket feed, and after a few seconds of steady output lets another process fire
``--messages`` malformed messages (garbage bytes and invalid msgpack maps, unregistered) as fast
as it can from one DEALER socket. Prints the feed's longest pause between two fused frames
around the burst, and what became of the well-formed agent's frames (rejected, sequence gaps:
it must lose nothing)::

    .venv/bin/python -m bench malformed_burst            # 12,000 messages, 3 repeats
    .venv/bin/python -m bench malformed_burst --repeat 5 --messages 20000

Each repeat uses fresh processes. ``tests/integration/test_malformed_burst.py`` runs one.
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import msgpack
import zmq

from skelfuse.client import FeedClient

SKELFUSE = [sys.executable, "-m", "skelfuse"]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@dataclass(frozen=True, slots=True)
class BurstResult:
    """One run: the longest pause of the feed (seconds) in the window from 1 s before the burst
    to 3 s after it, the burst's duration, and the agent's frames rejected / lost meanwhile."""

    longest_pause_s: float
    baseline_pause_s: float
    burst_s: float
    messages: int
    agent_rejected: int
    agent_gaps: int
    agent_frames: int
    refused: dict[str, int]


def malformed(i: int) -> bytes:
    """Cheap-to-make invalid messages of three kinds, cycled."""
    kind = i % 3
    if kind == 0:
        return b"\xc1" + i.to_bytes(4, "little")  # not msgpack
    if kind == 1:
        packed: bytes = msgpack.packb({"v": 1, "type": "frame", "seq": -i})  # bad field
        return packed
    packed = msgpack.packb([i, "not a map"])
    return packed


def flood(endpoint: str, messages: int) -> None:
    """Connect, print ``ready``, wait for a line on stdin, then send ``messages`` malformed
    messages as fast as possible from one DEALER; print the seconds it took. (Started ahead
    and triggered, so that starting a Python process is not inside the measured window.)"""
    context = zmq.Context()
    dealer = context.socket(zmq.DEALER)
    dealer.sndhwm = messages + 10
    dealer.linger = 2000
    dealer.connect(endpoint)
    time.sleep(0.3)  # connected
    payloads = [malformed(i) for i in range(messages)]
    print("ready", flush=True)
    sys.stdin.readline()
    started = time.perf_counter()
    for payload in payloads:
        dealer.send(payload)
    print(f"{time.perf_counter() - started:.4f}", flush=True)
    dealer.close()
    context.term()


def sensor_row(http: str) -> dict[str, object]:
    rows = httpx.get(http + "/api/sensors", timeout=10).json()
    row: dict[str, object] = next(r for r in rows["sensors"] if r["id"] == "cam-a")
    row["_refused"] = rows["rejected_unregistered"]
    return row


def run_once(messages: int, settle_s: float = 4.0) -> BurstResult:
    """Fresh server and agent processes, one burst; the processes are stopped after."""
    http_port, zmq_port = free_port(), free_port()
    endpoint = f"tcp://127.0.0.1:{zmq_port}"
    http = f"http://127.0.0.1:{http_port}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    quiet = {"env": env, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    with tempfile.TemporaryDirectory() as data:
        server = subprocess.Popen(
            [*SKELFUSE, "server", "--http", f"127.0.0.1:{http_port}", "--zmq", endpoint,
             "--data", str(Path(data))], **quiet,  # type: ignore[call-overload]
        )  # fmt: skip
        agent = subprocess.Popen(
            [*SKELFUSE, "agent", "--id", "cam-a", "--server", endpoint], **quiet,  # type: ignore[call-overload]
        )  # fmt: skip
        try:
            return asyncio.run(_measure(http, endpoint, messages, settle_s))
        finally:
            for process in (agent, server):
                process.terminate()
            for process in (agent, server):
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()


async def _measure(http: str, endpoint: str, messages: int, settle_s: float) -> BurstResult:
    deadline = time.monotonic() + 30
    while True:
        try:
            if sensor_row(http)["frames_received"] > 30:  # type: ignore[operator]
                break
        except (httpx.HTTPError, StopIteration):
            pass
        if time.monotonic() > deadline:
            raise RuntimeError("server and agent did not start streaming within 30 s")
        await asyncio.sleep(0.2)
    arrivals: list[float] = []

    async def read_feed() -> None:
        # Arrival stamped as the message is read, before it is decoded.
        async with FeedClient(http, reconnect=False, clock=time.monotonic) as feed:
            async for frame in feed:
                assert frame.received is not None
                arrivals.append(frame.received)

    flooder = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "bench", "malformed_burst", "--flood", endpoint,
        "--messages", str(messages), stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
    )  # fmt: skip
    assert flooder.stdout is not None
    await flooder.stdout.readline()  # ready
    reader = asyncio.create_task(read_feed())
    await asyncio.sleep(settle_s)
    before = await asyncio.to_thread(sensor_row, http)  # the reader keeps reading meanwhile
    burst_at = time.monotonic()
    out, _ = await flooder.communicate(b"go\n")
    await asyncio.sleep(3.0)
    reader.cancel()
    await asyncio.gather(reader, return_exceptions=True)
    after = await asyncio.to_thread(sensor_row, http)
    window = [t for t in arrivals if t >= burst_at - 1.0]
    baseline = [t for t in arrivals if t < burst_at - 1.0]

    def longest(times: list[float]) -> float:
        return max((b - a for a, b in itertools.pairwise(times)), default=float("inf"))

    rejected_before: dict[str, int] = before["frames_rejected"]  # type: ignore[assignment]
    rejected_after: dict[str, int] = after["frames_rejected"]  # type: ignore[assignment]
    return BurstResult(
        longest_pause_s=longest(window),
        baseline_pause_s=longest(baseline),
        burst_s=float(out.decode().strip() or "nan"),
        messages=messages,
        agent_rejected=sum(rejected_after.values()) - sum(rejected_before.values()),
        agent_gaps=int(after["sequence_gaps"]) - int(before["sequence_gaps"]),  # type: ignore[call-overload]
        agent_frames=int(after["frames_received"]) - int(before["frames_received"]),  # type: ignore[call-overload]
        refused=dict(after["_refused"]),  # type: ignore[call-overload]
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=12_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--flood", metavar="ENDPOINT", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.flood:
        flood(args.flood, args.messages)
        return
    pauses = []
    for run in range(args.repeat):
        result = run_once(args.messages)
        pauses.append(result.longest_pause_s)
        print(
            f"run {run + 1}: longest feed pause {result.longest_pause_s * 1000:.0f} ms "
            f"(before the burst {result.baseline_pause_s * 1000:.0f} ms); burst of "
            f"{result.messages} sent in {result.burst_s:.2f} s; agent: {result.agent_frames} "
            f"frames, {result.agent_rejected} rejected, {result.agent_gaps} lost; refused "
            f"from the flooder: {result.refused}",
            flush=True,
        )
    print(f"median longest pause {statistics.median(pauses) * 1000:.0f} ms, load {os.getloadavg()}")
