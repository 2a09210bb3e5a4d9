"""Outputs: plug-ins of one kind that take fused frames and send them somewhere (docs/outputs.md).

Everything the fusion loop publishes to is a :class:`FramePublisher`: ``publish(frame, now_s,
now_mono)`` that never blocks and never raises into fusion. The WebSocket feed's
:class:`~skelfuse.server.broadcast.Broadcaster` is one already (a one-frame mailbox per
client); :class:`Fanout` hands each frame to it and to every configured output in turn.

An output other than the feed is a :class:`QueuedOutput`: a bounded queue drained by a thread of
its own, which encodes the frame and sends it through its :class:`Sink` (OSC, VMC, LSL). Fusion
only puts the frame in the queue (about a microsecond); when the queue is full (the sink stalled:
a receiver gone with a full socket buffer, a slow encoder), the frame is dropped and counted, so
neither fusion nor another output waits. ``/metrics`` shows each output's ``sent`` and
``dropped`` (:class:`OutputsCollector`).
"""

from __future__ import annotations

import logging
import queue
import socket
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from skelfuse.fusion.engine import FusedFrame
from skelfuse.server.settings import OutputSpec

logger = logging.getLogger(__name__)
_STOP = object()


class FramePublisher(Protocol):
    """What the fusion loop publishes each fused frame to."""

    def publish(self, frame: FusedFrame, now_s: float, now_mono: float) -> None:
        """Take one frame without blocking (``now_s``: Unix seconds; ``now_mono``: monotonic)."""
        ...


class Sink(Protocol):
    """Where a :class:`QueuedOutput` sends: encodes a frame and sends it, in the output's
    thread. ``send`` returns how many of the frame's messages could not be sent (0: all)."""

    def send(self, frame: FusedFrame) -> int:
        """Encode and send one frame; the count of messages (datagrams, samples) not sent.

        Raises:
            Exception: anything; the output counts the frame as dropped and goes on.
        """
        ...

    def close(self) -> None:
        """Release the socket or stream."""
        ...


@dataclass(slots=True)
class QueuedOutput:
    """One output: a bounded queue of frames and the thread that sends them through ``sink``.

    sent: frames sent whole; dropped: frames not sent (the queue full when offered, or the sink
    failed or could not send all of it); messages_dropped: the sink's count of datagrams or
    samples it could not send (a full socket buffer).
    """

    name: str
    sink: Sink
    capacity: int = 8
    sent: int = 0
    dropped: int = 0
    messages_dropped: int = 0
    _queue: queue.Queue[object] = field(init=False)
    _thread: threading.Thread | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        self._queue = queue.Queue(maxsize=self.capacity)

    def start(self) -> None:
        """Start the sending thread (a daemon: it never holds the process open)."""
        self._thread = threading.Thread(target=self._run, name=f"output-{self.name}", daemon=True)
        self._thread.start()

    def publish(self, frame: FusedFrame, now_s: float, now_mono: float) -> None:
        """Queue the frame for the thread; a full queue drops it (counted)."""
        try:
            self._queue.put_nowait(frame)
        except queue.Full:
            self.dropped += 1

    def queued(self) -> int:
        return self._queue.qsize()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            assert isinstance(item, FusedFrame)
            try:
                lost = self.sink.send(item)
            except Exception:
                logger.warning("output %s failed to send a frame", self.name, exc_info=True)
                self.dropped += 1
                continue
            if lost:
                self.messages_dropped += lost
                self.dropped += 1
            else:
                self.sent += 1

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the thread once the frames queued are sent (at most ``timeout_s``), then close
        the sink."""
        thread = self._thread
        if thread is not None:
            try:
                self._queue.put(_STOP, timeout=timeout_s)
            except queue.Full:
                logger.warning("output %s still busy at close", self.name)
            thread.join(timeout_s)
        self.sink.close()


@dataclass(slots=True)
class Fanout:
    """The fusion loop's one publisher: the WebSocket feed, then each output, in order.

    An output that raises is logged and skipped for that frame: it cannot stop the others.
    """

    publishers: Sequence[FramePublisher]

    def publish(self, frame: FusedFrame, now_s: float, now_mono: float) -> None:
        for publisher in self.publishers:
            try:
                publisher.publish(frame, now_s, now_mono)
            except Exception:
                logger.exception("publishing a frame to %r failed", publisher)


class OutputsCollector(Collector):
    """``/metrics``: per output (``output`` label: its name, e.g. ``osc:127.0.0.1:9000``) the
    frames sent and dropped, the messages its sink could not send, and the frames queued."""

    def __init__(self, outputs: Sequence[QueuedOutput]) -> None:
        self.outputs = outputs

    def collect(self) -> Iterator[Metric]:
        sent = CounterMetricFamily(
            "skelfuse_output_sent", "Frames an output sent whole", labels=["output"]
        )
        dropped = CounterMetricFamily(
            "skelfuse_output_dropped",
            "Frames an output dropped (its queue full, or not all of it sent)",
            labels=["output"],
        )
        messages = CounterMetricFamily(
            "skelfuse_output_messages_dropped",
            "Datagrams or samples an output's sink could not send",
            labels=["output"],
        )
        queued = GaugeMetricFamily(
            "skelfuse_output_queued", "Frames waiting in an output's queue", labels=["output"]
        )
        for output in self.outputs:
            sent.add_metric([output.name], output.sent)
            dropped.add_metric([output.name], output.dropped)
            messages.add_metric([output.name], output.messages_dropped)
            queued.add_metric([output.name], output.queued())
        yield from (sent, dropped, messages, queued)


def output_name(spec: OutputSpec) -> str:
    """The output's name in logs and ``/metrics``: ``osc:HOST:PORT``, ``vmc:HOST:PORT``, ``lsl``,
    ``nats:HOST:PORT/ROOM``."""
    if spec.kind == "lsl":
        return "lsl"
    name = f"{spec.kind}:{spec.host}:{spec.port}"
    return f"{name}/{spec.room}" if spec.kind == "nats" else name


def build_output(spec: OutputSpec, rate_hz: float) -> QueuedOutput:
    """The output ``spec`` describes, its sink open and its thread not started yet.

    ``rate_hz``: the fused frame rate (LSL's nominal rate).

    Raises:
        ImportError: ``lsl`` without pylsl installed (``pip install 'skelfuse[lsl]'``).
        OSError: the UDP socket cannot be opened.
        ValueError: a nats room that is not one subject token.
    """
    sink: Sink
    if spec.kind == "nats":
        from skelfuse.server.output_nats import History, NatsSink

        history = History(spec.history_s, spec.history_msgs) if spec.jetstream else None
        host = f"[{spec.host}]" if ":" in spec.host else spec.host
        sink = NatsSink(f"nats://{host}:{spec.port}", spec.room, spec.rotations, history)
    elif spec.kind == "lsl":
        from skelfuse.server.output_lsl import LslSink

        # One source id per machine: LabRecorder re-finds the stream after a server restart.
        sink = LslSink(spec.slots, rate_hz, f"skelfuse@{socket.gethostname()}")
    else:
        from skelfuse.server.output_osc import OscSink, VmcSink

        sink = (
            OscSink(spec.host, spec.port, spec.rotations)
            if spec.kind == "osc"
            else VmcSink(spec.host, spec.port)
        )
    return QueuedOutput(output_name(spec), sink, spec.queue)
