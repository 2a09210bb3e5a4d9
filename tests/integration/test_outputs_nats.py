"""The NATS output against a real ``nats-server`` (Debian's package) on a free loopback port: a
nats-py subscriber gets every frame as the feed's msgpack message; with NATS stopped mid-run
frames are dropped and counted without an exception or a wait, and publishing resumes when it
is back; a late subscriber replays the JetStream history; a live server publishes what its
WebSocket feed sends. Without ``nats-server`` these skip with the reason, and fail under CI."""

from __future__ import annotations

import asyncio
import json
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import msgpack
import nats
import pytest
from nats.aio.client import Client
from websockets.sync.client import connect

from skelfuse.cli import build_parser
from skelfuse.cli.server import output_specs
from skelfuse.cli.values import UsageError
from skelfuse.protocol.feed import frame_json
from skelfuse.server.output_config import OutputConfigError, output_from_mapping
from skelfuse.server.output_nats import History, NatsSink, room_subject
from skelfuse.server.outputs import QueuedOutput, output_name
from skelfuse.server.settings import OutputSpec
from tests.integration.conftest import AgentThread, LiveServer, collect_feed
from tests.support import free_port, unavailable
from tests.unit.test_outputs_osc import fused_frames

FRAMES = 30


def _wait(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.01)


class NatsServer:
    """A ``nats-server`` on 127.0.0.1:``port`` with JetStream (its store in ``store``; ``domain``:
    its JetStream domain) and ``extra`` configuration, stopped and started again on the same
    port."""

    def __init__(self, binary: str, store: Path, domain: str = "", extra: str = "") -> None:
        self.binary, self.port = binary, free_port()
        self.url = f"nats://127.0.0.1:{self.port}"
        store.mkdir(parents=True, exist_ok=True)
        self.config = store / "nats.conf"
        jetstream = f'store_dir: "{store}"' + (f", domain: {domain}" if domain else "")
        self.config.write_text(
            f"listen: 127.0.0.1:{self.port}\njetstream {{ {jetstream} }}\n{extra}\n"
        )
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.process = subprocess.Popen(
            [self.binary, "-c", str(self.config)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        _wait(self._accepts, 10.0, f"nats-server on port {self.port}")

    def _accepts(self) -> bool:
        assert self.process is not None and self.process.poll() is None, "nats-server exited"
        try:
            socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
        except OSError:
            return False
        return True

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)


def nats_server_binary() -> str:
    """The ``nats-server`` executable (skips, or fails under CI, without it)."""
    binary = shutil.which("nats-server") or shutil.which("nats-server", path="/usr/sbin")
    if binary is None:
        unavailable(
            "nats-server not found (`nats-server` on PATH or in /usr/sbin)",
            "CI must install Debian's `nats-server` package (scripts/test.sh does)",
        )
    return binary


@pytest.fixture
def nats_server(tmp_path: Path) -> Iterator[NatsServer]:
    server = NatsServer(nats_server_binary(), tmp_path / "jetstream")
    server.start()
    yield server
    server.stop()


class Subscriber:
    """A nats-py client on an event loop in a thread, collecting a subject's messages decoded
    (``jetstream``: through an ordered consumer from the stream's first message)."""

    def __init__(self, url: str, subject: str, jetstream: bool = False) -> None:
        self.messages: list[dict[str, Any]] = []
        self.subjects: list[str] = []
        self.resubscribed = threading.Event()
        self.client: Client | None = None
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._start(url, subject, jetstream), self._loop).result(
            10
        )

    async def _start(self, url: str, subject: str, jetstream: bool) -> None:
        async def on_message(msg: Any) -> None:
            self.messages.append(msgpack.unpackb(msg.data))
            self.subjects.append(msg.subject)

        async def on_error(exc: Exception) -> None:
            pass  # NATS stopped on purpose; nats-py would log a traceback per attempt

        async def on_reconnected() -> None:
            assert self.client is not None
            await self.client.flush()  # the server has our subscription again
            self.resubscribed.set()

        self.client = await nats.connect(
            url,
            max_reconnect_attempts=-1,
            reconnect_time_wait=0.1,
            error_cb=on_error,
            reconnected_cb=on_reconnected,
        )
        if jetstream:
            await self.client.jetstream().subscribe(subject, cb=on_message, ordered_consumer=True)
        else:
            await self.client.subscribe(subject, cb=on_message)
        await self.client.flush()

    def close(self) -> None:
        if self.client is not None:
            asyncio.run_coroutine_threadsafe(self.client.close(), self._loop).result(5)
        asyncio.run_coroutine_threadsafe(_cancel_others(), self._loop).result(5)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        self._loop.close()


async def _cancel_others() -> None:
    """Cancel the loop's other tasks (nats-py's JetStream flow control outlives the client)."""
    others = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
    for task in others:
        task.cancel()
    await asyncio.gather(*others, return_exceptions=True)


def _feed_message(frame: Any) -> dict[str, Any]:
    """What the WebSocket feed sends for ``frame`` in msgpack, less ``t_sent``."""
    message: dict[str, Any] = msgpack.unpackb(msgpack.packb(frame_json(frame, False)))
    return message


def _started(url: str, room: str, history: History | None = None) -> QueuedOutput:
    output = QueuedOutput("nats", NatsSink(url, room, history=history), capacity=64)
    output.start()
    _wait(lambda: output.sink.connected, 10.0, "the output's connection")  # type: ignore[attr-defined]
    return output


def _publish(output: QueuedOutput, frames: list[Any]) -> list[float]:
    """Publish ``frames`` as fusion does; each publish call's seconds."""
    took = []
    for frame in frames:
        start = time.perf_counter()
        output.publish(frame, time.time(), time.monotonic())
        took.append(time.perf_counter() - start)
        _wait(lambda: output.queued() == 0, 5.0, "the output's queue to drain")
    return took


def test_a_subscriber_gets_every_frame_as_the_feed_message(nats_server: NatsServer) -> None:
    frames = fused_frames()
    subscriber = Subscriber(nats_server.url, "skelfuse.hall-a.frames")
    output = _started(nats_server.url, "hall-a")
    before = time.time()
    _publish(output, frames)
    _wait(lambda: len(subscriber.messages) >= FRAMES, 10.0, "every frame at the subscriber")
    output.close()
    subscriber.close()

    assert (output.sent, output.dropped) == (FRAMES, 0)
    assert [m["seq"] for m in subscriber.messages] == [f.seq for f in frames]
    for frame, message in zip(frames, subscriber.messages, strict=True):
        assert before <= message.pop("t_sent") <= time.time()
        assert message == _feed_message(frame)


def test_nats_down_drops_and_counts_then_publishing_resumes(nats_server: NatsServer) -> None:
    frames = fused_frames()
    subscriber = Subscriber(nats_server.url, room_subject("hall-b"))
    output = _started(nats_server.url, "hall-b")
    sink: NatsSink = output.sink  # type: ignore[assignment]
    _publish(output, frames[:10])
    _wait(lambda: len(subscriber.messages) == 10, 10.0, "the first 10 frames")

    nats_server.stop()
    _wait(lambda: not sink.connected, 10.0, "the output to see NATS gone")
    took = _publish(output, frames[10:20])  # never raises, never waits for NATS
    assert (output.sent, output.dropped) == (10, 10)
    assert max(took) < 0.05, "fusion's publish waited for NATS"

    nats_server.start()
    _wait(lambda: sink.connected and subscriber.resubscribed.is_set(), 20.0, "reconnections")
    _publish(output, frames[20:])
    _wait(lambda: len(subscriber.messages) == 20, 10.0, "the frames after the reconnection")
    output.close()
    subscriber.close()

    assert (output.sent, output.dropped) == (20, 10)
    assert (sink.disconnects, sink.reconnects) == (1, 1)
    expected = [f.seq for f in frames[:10] + frames[20:]]
    assert [m["seq"] for m in subscriber.messages] == expected


def test_a_late_subscriber_replays_the_jetstream_history(nats_server: NatsServer) -> None:
    frames = fused_frames()
    output = _started(nats_server.url, "hall-c", History(max_age_s=10.0, max_msgs=20))
    _publish(output, frames)
    output.close()
    late = Subscriber(nats_server.url, room_subject("hall-c"), jetstream=True)
    _wait(lambda: len(late.messages) >= 20, 10.0, "the replayed history")
    time.sleep(0.2)  # nothing beyond the retention comes after
    info: Any = None

    async def stream_info() -> None:
        nonlocal info
        client = await nats.connect(nats_server.url)
        info = await client.jetstream().stream_info("skelfuse-hall-c")
        await client.close()

    asyncio.run(stream_info())
    late.close()

    assert [m["seq"] for m in late.messages] == [f.seq for f in frames[10:]]
    assert late.messages[-1]["persons"] == _feed_message(frames[-1])["persons"]
    assert (info.config.max_age, info.config.max_msgs) == (10.0, 20)


def test_a_live_server_publishes_what_its_feed_sends(
    nats_server: NatsServer,
    server_factory: Callable[..., LiveServer],
    agent_factory: Callable[..., AgentThread],
) -> None:
    subscriber = Subscriber(nats_server.url, room_subject("stage"))
    spec = OutputSpec("nats", "127.0.0.1", nats_server.port, room="stage")
    live = server_factory(outputs=(spec,))
    agent_factory(live.zmq_url, "cam-a", (0.0, 1.0, 3.0), depth=False)
    agent_factory(live.zmq_url, "cam-b", (2.6, 1.0, -1.5), depth=False)
    feed = collect_feed(live.ws_url, FRAMES)
    metrics = httpx.get(live.http_url + "/metrics/").text
    live.stop()
    time.sleep(0.2)
    subscriber.close()

    received = {m["seq"]: m for m in subscriber.messages}
    seqs = sorted(received)
    assert seqs == list(range(seqs[0], seqs[-1] + 1)), "a NATS frame was lost"
    compared = 0
    # Frames fused before the output's connection are dropped (counted); every one after is here.
    for seq, message in feed.items():
        if seq >= seqs[0]:
            assert received[seq]["persons"] == message["persons"]
            assert received[seq]["t"] == message["t"]
            compared += bool(message["persons"])
    assert compared >= FRAMES - 2
    name = output_name(spec)
    assert name == f"nats:127.0.0.1:{nats_server.port}/stage"
    sent = float(metrics.split(f'skelfuse_output_sent_total{{output="{name}"}} ')[1].split()[0])
    assert sent >= compared - 2  # the last may still have been queued when /metrics was read
    assert f'skelfuse_output_dropped_total{{output="{name}"}}' in metrics


def test_a_live_server_without_nats_fuses_on_and_counts_its_drops(
    server_factory: Callable[..., LiveServer], agent_factory: Callable[..., AgentThread]
) -> None:
    spec = OutputSpec("nats", "127.0.0.1", free_port(), room="nobody")  # nothing listens
    live = server_factory(outputs=(spec,))
    agent_factory(live.zmq_url, "cam-a", (0.0, 1.0, 3.0), depth=False)
    with connect(f"{live.ws_url}/ws/skeletons", open_timeout=10) as ws:
        ws.recv(timeout=10)  # the skeleton definition
        fused = 0
        while fused < FRAMES:
            fused += bool(json.loads(ws.recv(timeout=10))["persons"])
    metrics = httpx.get(live.http_url + "/metrics/").text
    name = output_name(spec)
    dropped = metrics.split(f'skelfuse_output_dropped_total{{output="{name}"}} ')[1].split()[0]
    assert float(dropped) >= FRAMES
    assert f'skelfuse_output_sent_total{{output="{name}"}} 0.0' in metrics


def test_nats_outputs_from_toml_tables() -> None:
    spec = output_from_mapping({"kind": "nats", "room": "hall-a", "jetstream": True})
    assert (spec.port, spec.room, spec.jetstream, spec.history_s, spec.history_msgs) == (
        4222, "hall-a", True, 10, 0,
    )  # fmt: skip
    for bad in ("a.b", "hall*", ">", "", "x" * 65, "salle 1"):
        with pytest.raises(OutputConfigError, match="room"):
            output_from_mapping({"kind": "nats", "room": bad})
    with pytest.raises(OutputConfigError, match="history_s"):
        output_from_mapping({"kind": "nats", "history_s": 0})


def test_nats_flags() -> None:
    def specs(*argv: str) -> tuple[OutputSpec, ...]:
        return output_specs(build_parser().parse_args(["server", *argv]))

    (spec,) = specs("--nats", "10.0.0.5", "--nats-room", "hall-a", "--nats-history", "30")
    assert (spec.kind, spec.host, spec.port, spec.room) == ("nats", "10.0.0.5", 4222, "hall-a")
    assert (spec.jetstream, spec.history_s) == (True, 30)
    (spec,) = specs("--nats", "127.0.0.1:4333")
    assert (spec.port, spec.room, spec.jetstream) == (4333, "default", False)
    with pytest.raises(UsageError, match="room"):
        specs("--nats", "127.0.0.1", "--nats-room", "a.b")
