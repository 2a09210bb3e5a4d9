"""OSC, VMC and LSL outputs at the fused rate on loopback: frames lost, datagram sizes, time.

Fused frames of the golden take (``tests/data/golden/take.sfrec``, two persons), cycled with
fresh ``seq`` and ``t_s``, are published through one :class:`~skelfuse.server.outputs.Fanout`
to an OSC output (with rotations), a VMC output and an LSL output at ``--fps`` for
``--seconds``, paced by the wall clock as the fusion loop is. Receivers on loopback count what
arrives: OSC ``/skelfuse/frame`` messages and VMC ``/VMC/Ext/OK`` ones (python-osc decodes
every datagram), LSL samples through a real inlet. Reported per output: frames sent, dropped
and received, the largest datagram, the sink's time per frame (encode + send: p50, p99), and
the fanout's publish time (what fusion pays). Usage::

    .venv/bin/python -m bench outputs --seconds 60 --fps 30 [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import socket
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage

from skelfuse.fusion.engine import FusedFrame
from skelfuse.recording.replay import replay
from skelfuse.server.output_osc import OscSink, VmcSink
from skelfuse.server.outputs import Fanout, QueuedOutput, Sink

TAKE = Path(__file__).resolve().parents[2] / "tests" / "data" / "golden" / "take.sfrec"


class TimedSink:
    """A sink that records each ``send``'s duration (seconds)."""

    def __init__(self, sink: Sink) -> None:
        self.sink = sink
        self.durations: list[float] = []

    def send(self, frame: FusedFrame) -> int:
        started = time.perf_counter()
        lost = self.sink.send(frame)
        self.durations.append(time.perf_counter() - started)
        return lost

    def close(self) -> None:
        self.sink.close()


class UdpCounter:
    """Receives datagrams on loopback in a thread; counts those holding ``marker``."""

    def __init__(self, marker: str) -> None:
        self.marker = marker
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(0.1)
        self.port: int = self.socket.getsockname()[1]
        self.frames = 0
        self.datagrams = 0
        self.largest = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                datagram = self.socket.recv(65536)
            except TimeoutError:
                continue
            self.datagrams += 1
            self.largest = max(self.largest, len(datagram))
            for message in OscBundle(datagram):
                if isinstance(message, OscMessage) and message.address == self.marker:
                    self.frames += 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.socket.close()


def frames_at(rate_hz: float, count: int) -> list[FusedFrame]:
    """``count`` fused frames of the golden take with persons, cycled, renumbered from 1 and
    stamped on a ``rate_hz`` grid starting now."""
    source = [f for f in replay(TAKE) if f.persons]
    start = time.time()
    return [
        dataclasses.replace(source[k % len(source)], seq=k + 1, t_s=start + k / rate_hz)
        for k in range(count)
    ]


def run(seconds: float, fps: float) -> dict[str, object]:
    """Publish ``seconds`` × ``fps`` frames to the three outputs; the figures (module doc)."""
    import pylsl

    from skelfuse.server.output_lsl import LslSink

    count = round(seconds * fps)
    frames = frames_at(fps, count)
    osc_in, vmc_in = UdpCounter("/skelfuse/frame"), UdpCounter("/VMC/Ext/OK")
    source = f"skelfuse-bench-{uuid.uuid4()}"
    sinks = {
        "osc": TimedSink(OscSink("127.0.0.1", osc_in.port, rotations=True)),
        "vmc": TimedSink(VmcSink("127.0.0.1", vmc_in.port)),
        "lsl": TimedSink(LslSink(2, fps, source)),
    }
    outputs = {name: QueuedOutput(name, sink, 8) for name, sink in sinks.items()}
    (info,) = pylsl.resolve_byprop("source_id", source, 1, 10.0)
    inlet = pylsl.StreamInlet(info, max_buflen=int(seconds) + 10)
    inlet.open_stream(timeout=10.0)
    samples = [0]

    def pull() -> None:
        while samples[0] < count:
            sample, _ = inlet.pull_sample(timeout=2.0)
            if sample is None:
                return
            samples[0] += 1

    puller = threading.Thread(target=pull, daemon=True)
    puller.start()
    for output in outputs.values():
        output.start()
    fanout = Fanout(list(outputs.values()))
    publish: list[float] = []
    started = time.perf_counter()
    for k, frame in enumerate(frames):
        delay = started + k / fps - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        before = time.perf_counter()
        fanout.publish(frame, time.time(), time.monotonic())
        publish.append(time.perf_counter() - before)
    for output in outputs.values():
        output.close(timeout_s=10.0)
    puller.join(timeout=10.0)
    time.sleep(0.3)  # the last datagrams
    osc_in.close()
    vmc_in.close()
    received = {"osc": osc_in.frames, "vmc": vmc_in.frames, "lsl": samples[0]}
    largest = {"osc": osc_in.largest, "vmc": vmc_in.largest}
    report: dict[str, object] = {
        "frames": count,
        "fps": fps,
        "publish_ms": _quantiles(publish),
    }
    for name, output in outputs.items():
        report[name] = {
            "sent": output.sent,
            "dropped": output.dropped,
            "received": received[name],
            "lost": count - received[name],
            "largest_datagram": largest.get(name),
            "send_ms": _quantiles(sinks[name].durations),
        }
    return report


def _quantiles(seconds: list[float]) -> dict[str, float]:
    values = np.array(seconds) * 1e3
    return {
        "p50": round(float(np.percentile(values, 50)), 3),
        "p99": round(float(np.percentile(values, 99)), 3),
        "max": round(float(values.max()), 3),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    report = run(args.seconds, args.fps)
    text = json.dumps(report, indent=2)
    if args.json is not None:
        args.json.write_text(text + "\n")
    sys.stdout.write(text + "\n")
    return 0
