"""NATS fan-out of many rooms through one hub on loopback: frames lost, room → subscriber latency.

Starts real ``nats-server`` processes as docs/outputs.md deploys them: a hub, and per room a
NATS server joined to it as a leaf node. Per room, a :class:`~skelfuse.server.outputs.
QueuedOutput` with a :class:`~skelfuse.server.output_nats.NatsSink` publishes fused frames at
``--fps`` for ``--seconds`` (the golden take's persons, copied to ``--persons`` with their own
ids; fresh ``seq`` per frame), paced by the wall clock as fusion is, room ``r`` ``r / rooms``
of a frame period after room 0 (rooms are separate servers; ``--lockstep``: all at once).
``--subscribers`` nats-py connections to the hub, spread over ``--processes`` processes,
subscribe to one room each
(subscriber ``k`` to room ``k % rooms``); each decodes every message and takes the latency as
its arrival (wall clock) minus the message's ``t_sent``. Reported: frames published, dropped,
expected and received at the subscribers, lost, latency p50 / p99 / max; with ``--late``,
room 0's server keeps 10 s of frames in JetStream and a subscriber joining at the hub after
the run replays them (frames, consecutive or not, their span, the replay's time). Usage::

    .venv/bin/python -m bench nats_fanout --rooms 10 --subscribers 200 --seconds 20 [--late]
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import multiprocessing
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgpack
import nats
import numpy as np

from skelfuse.fusion.engine import FusedFrame
from skelfuse.recording.replay import replay
from skelfuse.server.output_nats import History, NatsSink, frame_payload, room_subject
from skelfuse.server.outputs import QueuedOutput

TAKE = Path(__file__).resolve().parents[2] / "tests" / "data" / "golden" / "take.sfrec"


def free_ports(count: int) -> list[int]:
    """``count`` distinct free loopback TCP ports."""
    import socket

    sockets = [socket.socket() for _ in range(count)]
    for s in sockets:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in sockets]
    for s in sockets:
        s.close()
    return ports


def start_servers(
    rooms: int, root: Path, history: bool
) -> tuple[list[subprocess.Popen[bytes]], str, list[str]]:
    """A hub and ``rooms`` leaf NATS servers (``history``: room 0's with JetStream, domain
    ``room0``); (processes, hub url, room urls).

    Raises:
        RuntimeError: no ``nats-server``.
    """
    binary = shutil.which("nats-server") or shutil.which("nats-server", path="/usr/sbin")
    if binary is None:
        raise RuntimeError("nats-server not found: apt-get install nats-server")
    hub, leaf, *room_ports = free_ports(rooms + 2)
    configs = [f"listen: 127.0.0.1:{hub}\nleafnodes {{ listen: 127.0.0.1:{leaf} }}\n"]
    remote = f'leafnodes {{ remotes: [ {{ url: "nats-leaf://127.0.0.1:{leaf}" }} ] }}\n'
    configs += [f"listen: 127.0.0.1:{port}\n{remote}" for port in room_ports]
    if history:
        configs[1] += f'jetstream {{ store_dir: "{root / "room0"}", domain: room0 }}\n'
    processes = []
    for k, text in enumerate(configs):
        path = root / f"nats-{k}.conf"
        path.write_text(text)
        processes.append(subprocess.Popen([binary, "-c", str(path)], stderr=subprocess.DEVNULL))
    time.sleep(1.5)  # the leaf links connect after a second at most on loopback
    return processes, f"nats://127.0.0.1:{hub}", [f"nats://127.0.0.1:{p}" for p in room_ports]


def template_frames(persons: int) -> list[FusedFrame]:
    """Frames of the golden take with people, each person copied to ``persons`` ids."""
    frames = []
    for frame in replay(TAKE):
        if not frame.persons:
            continue
        people = [
            dataclasses.replace(frame.persons[k % len(frame.persons)], person_id=k + 1)
            for k in range(persons)
        ]
        frames.append(dataclasses.replace(frame, persons=tuple(people)))
        if len(frames) == 30:
            break
    return frames


def subscribe(hub: str, indices: list[int], rooms: int, seconds: float, out: Any) -> None:
    """A process of subscribers: per subscriber, the seqs received and latencies (seconds)."""

    async def main() -> dict[int, tuple[list[int], list[float]]]:
        got: dict[int, tuple[list[int], list[float]]] = {k: ([], []) for k in indices}
        clients = []
        for k in indices:
            client = await nats.connect(hub)

            async def on_message(msg: Any, k: int = k) -> None:
                arrived = time.time()
                message = msgpack.unpackb(msg.data)
                got[k][0].append(message["seq"])
                got[k][1].append(arrived - message["t_sent"])

            await client.subscribe(room_subject(f"room{k % rooms}"), cb=on_message)
            await client.flush()
            clients.append(client)
        out.put("ready")
        await asyncio.sleep(seconds)
        for client in clients:
            await client.close()
        return got

    out.put(asyncio.run(main()))


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Run the bench; the report as a dict."""
    with tempfile.TemporaryDirectory() as tmp:
        processes, hub, room_urls = start_servers(args.rooms, Path(tmp), args.late)
        try:
            return _measure(args, hub, room_urls)
        finally:
            for process in processes:
                process.terminate()
                process.wait(5)


def _measure(args: argparse.Namespace, hub: str, room_urls: list[str]) -> dict[str, Any]:
    frames = template_frames(args.persons)
    payload = len(frame_payload(frames[0], time.time(), False))
    queue: Any = multiprocessing.get_context("spawn").Queue()
    per_process = np.array_split(np.arange(args.subscribers), args.processes)
    listen_s = args.seconds + 5.0
    workers = [
        multiprocessing.get_context("spawn").Process(
            target=subscribe, args=(hub, [int(k) for k in part], args.rooms, listen_s, queue)
        )
        for part in per_process
    ]
    for worker in workers:
        worker.start()
    for _ in workers:
        queue.get(timeout=120)
    time.sleep(1.0)  # the subscriptions reach the rooms' leaf servers
    history = History(max_age_s=10.0) if args.late else None
    outputs = [
        QueuedOutput(f"room{r}", NatsSink(url, f"room{r}", history=history if r == 0 else None))
        for r, url in enumerate(room_urls)
    ]
    for output in outputs:
        output.start()
    while not all(o.sink.connected for o in outputs):  # type: ignore[attr-defined]
        time.sleep(0.01)
    count = int(args.seconds * args.fps)
    start = time.monotonic()
    # Rooms are separate servers, not in step: room r publishes r / rooms of a period later
    # (--lockstep: all at once, the worst case for the subscribers' bursts).
    offsets = [0.0 if args.lockstep else r / (args.rooms * args.fps) for r in range(args.rooms)]
    for n in range(count):
        for output, offset in zip(outputs, offsets, strict=True):
            time.sleep(max(0.0, start + n / args.fps + offset - time.monotonic()))
            frame = dataclasses.replace(frames[n % len(frames)], seq=n, t_s=time.time())
            output.publish(frame, time.time(), time.monotonic())
    for output in outputs:
        output.close()
    late = asyncio.run(replay_late(hub)) if args.late else {}
    results: dict[int, tuple[list[int], list[float]]] = {}
    for _ in workers:
        results.update(queue.get(timeout=listen_s + 60))
    for worker in workers:
        worker.join(10)
    published = sum(o.sent for o in outputs)
    latencies = np.concatenate([np.array(lat) for _, lat in results.values()])
    expected = sum(outputs[k % args.rooms].sent for k in results)
    received = sum(len(seqs) for seqs, _ in results.values())
    return {
        "rooms": args.rooms,
        "subscribers": args.subscribers,
        "fps": args.fps,
        "seconds": args.seconds,
        "persons": args.persons,
        "lockstep": args.lockstep,
        "payload_bytes": payload,
        "published": published,
        "dropped": sum(o.dropped for o in outputs),
        "expected": expected,
        "received": received,
        "lost": expected - received,
        "latency_ms_p50": round(float(np.percentile(latencies, 50)) * 1e3, 2),
        "latency_ms_p99": round(float(np.percentile(latencies, 99)) * 1e3, 2),
        "latency_ms_max": round(float(latencies.max()) * 1e3, 2),
        **late,
    }


async def replay_late(hub: str) -> dict[str, Any]:
    """A subscriber joining room 0 at the hub after the run: its JetStream history (domain
    ``room0``) read whole: frames, whether their seqs are consecutive, the fused instants'
    span (seconds) and the time the replay took."""
    client = await nats.connect(hub)
    js = client.jetstream(domain="room0")
    count = (await js.stream_info("skelfuse-room0")).state.messages
    started = time.perf_counter()
    subscription = await js.subscribe(room_subject("room0"), ordered_consumer=True)
    messages = [msgpack.unpackb((await subscription.next_msg(5)).data) for _ in range(count)]
    took = time.perf_counter() - started
    await client.close()
    seqs = [m["seq"] for m in messages]
    return {
        "late_replayed": count,
        "late_consecutive": seqs == list(range(seqs[0], seqs[0] + count)),
        "late_span_s": round(messages[-1]["t"] - messages[0]["t"], 3),
        "late_replay_s": round(took, 3),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=10)
    parser.add_argument("--subscribers", type=int, default=200)
    parser.add_argument("--processes", type=int, default=2, help="subscriber processes")
    parser.add_argument("--persons", type=int, default=6)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--lockstep", action="store_true", help="all rooms publish at once")
    parser.add_argument(
        "--late", action="store_true", help="room 0 keeps 10 s in JetStream; replay it after"
    )
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    report = run(args)
    text = json.dumps(report, indent=2)
    sys.stdout.write(text + "\n")
    if args.json is not None:
        args.json.write_text(text + "\n")
    return 0
