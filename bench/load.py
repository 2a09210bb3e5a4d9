"""Load benchmark: the real server under N agents × 30 fps × B bodies and 21 WebSocket clients.

Everything runs on loopback (127.0.0.1) on free ports and stops by itself:

- the fusion server as a subprocess (``python -m skelfuse server``), with a temporary data folder
  holding a stored calibration for the fake sensors (so every body is fused from the first frame);
- N fake agents in one child process: one real ZeroMQ DEALER per agent (``agent.link.AgentLink``:
  hello, welcome, heartbeats, non-blocking sends), each sending 30 frames per second at its own
  random phase, B bodies per frame, every joint TRACKED. The bodies are
  ``ProceduralPerformer(B)`` (people walking circles, squatting, raising arms) sampled on a
  30 Hz grid, linearly interpolated to each capture instant and moved into each sensor's frame;
- 20 healthy WebSocket clients (JSON) reading everything, and 1 client that completes the
  handshake and then never reads (4 KiB receive buffer, so it stalls within seconds).

Measured over a window that starts after all sensors are online and a warm-up:

- ingest: frames sent by the agents vs frames received by the server (``GET /api/sensors``),
  agent-side drops, ``sequence_gaps``, ``frames_rejected``;
- output: fused frames per second (``GET /api/health`` ``fused_frames``) and per healthy client
  (``seq``), gaps in ``seq`` per client;
- latency: client receive wall time − the fused frame's ``t`` (same machine, same clock), and the
  server's share ``t_sent − t``. The server fuses instant ``t`` of its 30 Hz grid once *every*
  live sensor has a frame past ``t``, so up to one frame period (33 ms) of deliberate alignment
  wait is part of that figure by design. The agents record every capture instant, so the bench
  computes that wait exactly for each fused frame (capture time of the last frame the instant
  needed, minus ``t``) and also reports the latency beyond it: client receive time − capture time
  of the frame that completed the instant;
- server CPU (% of one core) and RSS from ``/proc/<pid>`` (Linux);
- the stalled client: when it was evicted (``GET /api/clients``), frames sent to / dropped for
  it, and the healthy clients' latency while it was connected vs after.

Separately, in-process: the fusion compute per fused frame (``FusionHub.fuse_step`` and the
``FusionPipeline.update`` inside it), the per-frame JSON encode, and ``handle_message`` per
incoming frame, median over 1000 steps.

Run: ``python bench/load.py`` (main run: 10 agents × 6 bodies, 120 s), ``--scaling`` (agents in
1, 2, 4, 8, 16 × bodies in 1, 6, 15 s each), ``--repeat K`` (K runs per configuration, medians
reported), ``--agents``, ``--bodies``, ``--duration``, ``--clients``, ``--stalled``,
``--fusion-only`` (the in-process timing only), ``--json FILE`` (raw results).
"""

from __future__ import annotations

import argparse
import asyncio
import heapq
import json
import math
import multiprocessing as mp
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from functools import partial
from multiprocessing.synchronize import Event as MpEvent
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from skelfuse.agent.link import AgentLink
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.calibration.store import Calibration, CalibrationStore, SensorCalibration
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, invert, look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello, encode

ROOT = Path(__file__).resolve().parents[1]
FPS = 30.0
PERIOD_S = 1.0 / FPS
SENSOR_RADIUS_M = 5.0
FloatArray = npt.NDArray[np.float64]

# Targets of the load issue (docs/benchmarks.md, /work/shared/reliability.md L1/L2).
TARGET_P50_MS = 10.0
TARGET_P99_MS = 30.0
TARGET_FUSE_MS = 1.0


# --- setup helpers -----------------------------------------------------------------------------


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def sensor_layout(count: int) -> dict[str, Matrix4]:
    """``count`` sensors on a 5 m circle, 1 m high, all looking at the middle of the room."""
    poses: dict[str, Matrix4] = {}
    for i in range(count):
        angle = 2 * math.pi * i / count
        position = (SENSOR_RADIUS_M * math.sin(angle), 1.0, SENSOR_RADIUS_M * math.cos(angle))
        poses[f"load-{i + 1:02d}"] = look_at_pose(position, (0.0, 1.0, 0.0))
    return poses


def http_json(url: str, timeout_s: float = 5.0) -> Any:
    with urllib.request.urlopen(url, timeout=timeout_s) as response:
        return json.load(response)


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (Linux ``/proc/<pid>/stat``)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_rss_mb(pid: int) -> float:
    """Resident set size in MB (Linux ``/proc/<pid>/statm``)."""
    pages = int(Path(f"/proc/{pid}/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


class WorldMotion:
    """The performer's world joints at any instant: a 30 Hz grid, linearly interpolated.

    ``ProceduralPerformer.joints_at`` costs about 1 ms for six people; sampling it once per
    grid step instead of once per agent frame keeps the agents process light with 16 agents.
    """

    def __init__(self, bodies: int) -> None:
        self._performer = ProceduralPerformer(bodies)
        self._t0 = time.time()
        self._cache: dict[int, FloatArray] = {}

    def _grid(self, k: int) -> FloatArray:
        joints = self._cache.get(k)
        if joints is None:
            joints = self._performer.joints_at(k * PERIOD_S)
            self._cache[k] = joints
            for old in [key for key in self._cache if key < k - 2]:
                del self._cache[old]
        return joints

    def at(self, t_s: float) -> FloatArray:
        x = (t_s - self._t0) * FPS
        k = math.floor(x)
        a = x - k
        out: FloatArray = (1 - a) * self._grid(k) + a * self._grid(k + 1)
        return out


# --- the agents (child process) ------------------------------------------------------------------


def _hello(sensor_id: str) -> Hello:
    return Hello(sensor_id, "sim", "bench-load", FPS, time.time_ns())


def agents_process(
    endpoint: str,
    poses: dict[str, list[float]],
    bodies: int,
    seed: int,
    max_runtime_s: float,
    stop: MpEvent,
    results: mp.Queue[Any],
) -> None:
    """Run every fake agent in one thread, each on its own 30 fps schedule, until ``stop``."""
    import zmq

    ids = sorted(poses)
    sensor_from_world = [invert(np.asarray(poses[s]).reshape(4, 4)) for s in ids]
    motion = WorldMotion(bodies)
    states = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)
    context: zmq.Context[Any] = zmq.Context()
    links = [AgentLink(endpoint, partial(_hello, s), context=context) for s in ids]
    rng = random.Random(seed)
    start = time.time() + 0.05
    due: list[tuple[float, int]] = [(start + rng.random() * PERIOD_S, i) for i in range(len(ids))]
    heapq.heapify(due)
    seqs = [0] * len(ids)
    captures: list[list[float]] = [[] for _ in ids]
    dropped_registered = [0] * len(ids)
    late = 0
    deadline = time.monotonic() + max_runtime_s
    while not stop.is_set() and time.monotonic() < deadline:
        when, i = due[0]
        now = time.time()
        if when > now:
            time.sleep(min(when - now, 0.02))
            continue
        heapq.heappop(due)
        t_ns = time.time_ns()
        seqs[i] += 1
        world = motion.at(t_ns / 1e9)
        frame = Frame(
            seqs[i],
            t_ns,
            tuple(
                Body(
                    i * 100 + b + 1,
                    apply(sensor_from_world[i], world[b]).astype(np.float32),
                    states,
                )
                for b in range(bodies)
            ),
        )
        registered = links[i].registered
        if links[i].send_frame(frame):
            captures[i].append(t_ns / 1e9)
        elif registered:
            dropped_registered[i] += 1
        links[i].poll(0.0)
        nxt = when + PERIOD_S
        if nxt < now - PERIOD_S:  # this process fell more than a frame behind: skip ahead
            late += 1
            nxt = now + PERIOD_S
        heapq.heappush(due, (nxt, i))
    out = {
        s: {
            "captured": seqs[i],
            "sent": links[i].stats.frames_sent,
            "dropped_unregistered": links[i].stats.frames_dropped - dropped_registered[i],
            "dropped_registered": dropped_registered[i],
            "registrations": links[i].stats.registrations,
            "captures": captures[i],
        }
        for i, s in enumerate(ids)
    }
    for link in links:
        link.close()
    context.term()
    results.put({"agents": out, "late": late})


# --- one run -------------------------------------------------------------------------------------


@dataclass
class RunConfig:
    agents: int
    bodies: int
    duration_s: float
    warmup_s: float = 3.0
    clients: int = 20
    stalled: int = 1


@dataclass
class RunResult:
    config: RunConfig
    window_s: float = 0.0
    agent_frames_sent: int = 0
    agent_drops_registered: int = 0
    server_frames_received: int = 0
    lost_frames: int = 0
    sequence_gaps: int = 0
    frames_rejected: int = 0
    rejected_reasons: dict[str, int] = field(default_factory=dict)
    agent_drops_unregistered: int = 0
    ingest_fps: float = 0.0
    fused_fps: float = 0.0
    client_fps_min: float = 0.0
    client_fps_median: float = 0.0
    client_gaps_total: int = 0
    client_gaps_max: int = 0
    skipped_instants: int = 0
    latency_p50_ms: float = math.nan
    latency_p99_ms: float = math.nan
    latency_max_ms: float = math.nan
    server_p50_ms: float = math.nan
    server_p99_ms: float = math.nan
    wait_p50_ms: float = math.nan
    wait_p99_ms: float = math.nan
    beyond_p50_ms: float = math.nan
    beyond_p99_ms: float = math.nan
    server_beyond_p50_ms: float = math.nan
    server_beyond_p99_ms: float = math.nan
    p99_while_stalled_ms: float = math.nan
    p99_after_evicted_ms: float = math.nan
    server_cpu_pct: float = 0.0
    server_rss_start_mb: float = 0.0
    server_rss_end_mb: float = 0.0
    server_rss_max_mb: float = 0.0
    persons_last: int = 0
    stalled_evicted_after_s: float | None = None
    stalled_sent: int = 0
    stalled_dropped: int = 0
    evicted_total: int = 0
    agents_late: int = 0
    notes: list[str] = field(default_factory=list)


@dataclass
class ClientLog:
    records: list[tuple[float, int, float, float]] = field(default_factory=list)
    error: str | None = None


async def healthy_client(url: str, log: ClientLog) -> None:
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


def _pct(values: Sequence[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) * 1e3 if len(values) else math.nan


def alignment_waits(
    fused_t: FloatArray, captures: dict[str, FloatArray], offsets: dict[str, float]
) -> FloatArray:
    """Per fused instant: capture time of the last frame it needed, minus the instant.

    The server maps a capture stamp onto its clock by adding the sensor's estimated offset, and
    fuses instant ``t`` once every sensor has a frame at or past ``t``; the frame that completes
    ``t`` is, per sensor, the first one with ``capture + offset >= t``.
    """
    completing = np.full(fused_t.shape, -np.inf)
    for sensor_id, caps in captures.items():
        if not len(caps):
            continue
        offset = offsets.get(sensor_id, 0.0)
        idx = np.searchsorted(caps + offset, fused_t, side="left")
        first = caps[np.minimum(idx, len(caps) - 1)]
        first = np.where(idx < len(caps), first, np.nan)
        completing = np.fmax(completing, first)
    out: FloatArray = completing - fused_t
    return out


def start_server(
    poses: dict[str, Matrix4], http_port: int, zmq_port: int, log_path: Path
) -> tuple[subprocess.Popen[bytes], IO[bytes]]:
    """``python -m skelfuse server`` on loopback, with a stored calibration for ``poses``."""
    data_dir = Path(tempfile.mkdtemp(prefix="skelfuse-load-"))
    CalibrationStore(data_dir).save(
        {s: SensorCalibration(pose, "bench") for s, pose in poses.items()}, note="bench/load.py"
    )
    log_file = log_path.open("wb")
    server = subprocess.Popen(
        [sys.executable, "-m", "skelfuse", "--log-level", "WARNING", "server",
         "--http", f"127.0.0.1:{http_port}", "--zmq", f"tcp://127.0.0.1:{zmq_port}",
         "--data", str(data_dir)],
        stdout=log_file, stderr=subprocess.STDOUT, cwd=ROOT,
    )  # fmt: skip
    return server, log_file


async def run_once(config: RunConfig, seed: int, log_dir: Path) -> RunResult:
    result = RunResult(config)
    http_port, zmq_port = free_port(), free_port()
    base = f"http://127.0.0.1:{http_port}"
    poses = sensor_layout(config.agents)
    log_path = log_dir / f"server-{config.agents}x{config.bodies}-{seed}.log"
    server, log_file = start_server(poses, http_port, zmq_port, log_path)
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    queue: mp.Queue[Any] = ctx.Queue()
    agents: mp.process.BaseProcess | None = None
    tasks: list[asyncio.Task[None]] = []
    stalled: list[tuple[socket.socket, int, float]] = []
    try:
        await asyncio.to_thread(
            wait_for, lambda: http_json(base + "/api/health"), 20, "the server to start"
        )
        logs = [ClientLog() for _ in range(config.clients)]
        ws_url = f"ws://127.0.0.1:{http_port}/ws/skeletons"
        tasks = [asyncio.create_task(healthy_client(ws_url, log)) for log in logs]
        for _ in range(config.stalled):
            sock, port = await asyncio.to_thread(open_stalled_client, http_port)
            stalled.append((sock, port, time.time()))
        agents = ctx.Process(
            target=agents_process,
            args=(
                f"tcp://127.0.0.1:{zmq_port}",
                {s: [float(x) for x in p.reshape(16)] for s, p in poses.items()},
                config.bodies, seed, config.warmup_s + config.duration_s + 60.0, stop, queue,
            ),
            daemon=True,
        )  # fmt: skip
        agents.start()

        def all_online() -> bool:
            health = http_json(base + "/api/health")
            return bool(health["sensors_online"] == config.agents and health["fused_frames"] > 30)

        await asyncio.to_thread(wait_for, all_online, 30, "every sensor online and fusing")
        await asyncio.sleep(config.warmup_s)

        async def snapshot() -> tuple[float, float, dict[str, Any], dict[str, Any]]:
            t = time.time()
            cpu = proc_cpu_s(server.pid)
            sensors, health = await asyncio.gather(
                get(base + "/api/sensors"), get(base + "/api/health")
            )
            return t, cpu, sensors, health

        t0, cpu0, sensors0, health0 = await snapshot()
        result.server_rss_start_mb = proc_rss_mb(server.pid)
        rss_max = result.server_rss_start_mb
        stalled_seen: dict[int, dict[str, Any]] = {}
        evicted_at: dict[int, float] = {}
        end = t0 + config.duration_s
        while (now := time.time()) < end:
            await asyncio.sleep(min(1.0, end - now))
            rss_max = max(rss_max, proc_rss_mb(server.pid))
            clients = await get(base + "/api/clients")
            for _, port, _ in stalled:
                entry = next(
                    (c for c in clients["clients"] if str(c["remote"]).endswith(f"{port})")), None
                )
                if entry is not None:
                    stalled_seen[port] = entry
                elif port not in evicted_at:
                    evicted_at[port] = time.time()
        t1, cpu1, sensors1, health1 = await snapshot()
        result.server_rss_end_mb = proc_rss_mb(server.pid)
        result.server_rss_max_mb = max(rss_max, result.server_rss_end_mb)
        result.window_s = t1 - t0
        result.server_cpu_pct = 100 * (cpu1 - cpu0) / result.window_s
        result.persons_last = int(health1["persons"])
        result.evicted_total = int((await get(base + "/api/clients"))["evicted"])

        stop.set()
        agent_out: dict[str, Any] = await asyncio.to_thread(queue.get, True, 30)
        await asyncio.to_thread(agents.join, 10)
        await asyncio.sleep(0.5)  # the last frames in flight
        sensors_end = await get(base + "/api/sensors")
    finally:
        stop.set()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for sock, _, _ in stalled:
            sock.close()
        if agents is not None and agents.is_alive():
            agents.kill()
        server.send_signal(2)
        try:
            server.wait(timeout=15)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        log_file.close()

    # --- ingest -----------------------------------------------------------------------------
    per_agent = agent_out["agents"]
    result.agents_late = int(agent_out["late"])
    received_end = {s["id"]: s for s in sensors_end["sensors"]}
    result.agent_frames_sent = sum(a["sent"] for a in per_agent.values())
    result.agent_drops_registered = sum(a["dropped_registered"] for a in per_agent.values())
    result.agent_drops_unregistered = sum(a["dropped_unregistered"] for a in per_agent.values())
    reasons: dict[str, int] = dict(sensors_end["rejected_unregistered"])
    for s in received_end.values():
        for reason, n in s["frames_rejected"].items():
            reasons[reason] = reasons.get(reason, 0) + n
    result.rejected_reasons = reasons
    result.server_frames_received = sum(s["frames_received"] for s in received_end.values())
    result.lost_frames = result.agent_frames_sent - result.server_frames_received
    result.sequence_gaps = sum(s["sequence_gaps"] for s in received_end.values())
    result.frames_rejected = sum(
        sum(s["frames_rejected"].values()) for s in received_end.values()
    ) + sum(sensors_end["rejected_unregistered"].values())
    rx0 = sum(s["frames_received"] for s in sensors0["sensors"])
    rx1 = sum(s["frames_received"] for s in sensors1["sensors"])
    result.ingest_fps = (rx1 - rx0) / result.window_s
    result.fused_fps = (health1["fused_frames"] - health0["fused_frames"]) / result.window_s
    offsets = {s["id"]: float(s["clock_offset_s"] or 0.0) for s in sensors1["sensors"]}
    captures = {s: np.asarray(a["captures"], dtype=np.float64) for s, a in per_agent.items()}

    # --- clients ----------------------------------------------------------------------------
    fps: list[float] = []
    gaps: list[int] = []
    skipped: list[int] = []
    latency: list[float] = []
    server_share: list[float] = []
    beyond: list[float] = []
    server_beyond: list[float] = []
    waits_all: list[float] = []
    evicted = min(evicted_at.values()) if evicted_at else None
    stalled_lat: list[float] = []
    after_lat: list[float] = []
    for log in logs:
        if log.error:
            result.notes.append(f"a healthy client failed: {log.error}")
        rows = np.asarray([r for r in log.records if t0 <= r[0] <= t1], dtype=np.float64)
        if not len(rows):
            fps.append(0.0)
            continue
        fps.append(len(rows) / result.window_s)
        seqs = rows[:, 1].astype(np.int64)
        gaps.append(int(np.sum(np.maximum(np.diff(seqs) - 1, 0))))
        # seq counts frames produced; instants of the 30 Hz grid the server never fused
        # (it resyncs to the newest instant when fusion falls behind) show in t only.
        steps = np.rint(np.diff(rows[:, 2]) * FPS).astype(np.int64)
        skipped.append(int(np.sum(np.maximum(steps - 1, 0))))
        lat = rows[:, 0] - rows[:, 2]
        waits = alignment_waits(rows[:, 2], captures, offsets)
        latency.extend(lat)
        server_share.extend(rows[:, 3] - rows[:, 2])
        ok = np.isfinite(waits)
        waits_all.extend(waits[ok])
        beyond.extend((lat - waits)[ok])
        server_beyond.extend((rows[:, 3] - rows[:, 2] - waits)[ok])
        if evicted is not None:
            stalled_lat.extend(lat[rows[:, 0] < evicted])
            after_lat.extend(lat[rows[:, 0] >= evicted])
    result.client_fps_min = min(fps) if fps else 0.0
    result.client_fps_median = statistics.median(fps) if fps else 0.0
    result.client_gaps_total = sum(gaps)
    result.client_gaps_max = max(gaps, default=0)
    result.skipped_instants = int(statistics.median(skipped)) if skipped else 0
    result.latency_p50_ms = _pct(latency, 50)
    result.latency_p99_ms = _pct(latency, 99)
    result.latency_max_ms = _pct(latency, 100)
    result.server_p50_ms = _pct(server_share, 50)
    result.server_p99_ms = _pct(server_share, 99)
    result.wait_p50_ms = _pct(waits_all, 50)
    result.wait_p99_ms = _pct(waits_all, 99)
    result.beyond_p50_ms = _pct(beyond, 50)
    result.beyond_p99_ms = _pct(beyond, 99)
    result.server_beyond_p50_ms = _pct(server_beyond, 50)
    result.server_beyond_p99_ms = _pct(server_beyond, 99)
    result.p99_while_stalled_ms = _pct(stalled_lat, 99)
    result.p99_after_evicted_ms = _pct(after_lat, 99)

    # --- the stalled client -----------------------------------------------------------------
    if stalled:
        _, port, connected = stalled[0]
        if port in evicted_at:
            result.stalled_evicted_after_s = evicted_at[port] - connected
        last = stalled_seen.get(port)
        if last is not None:
            result.stalled_sent = int(last["sent"])
            result.stalled_dropped = int(last["dropped"])
        elif port not in evicted_at:
            result.notes.append("the stalled client never appeared in /api/clients")
    return result


async def get(url: str) -> Any:
    return await asyncio.to_thread(http_json, url)


def wait_for(predicate: Callable[[], object], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    last: Exception | None = None
    while time.monotonic() < deadline:
        try:
            if predicate():
                return
        except Exception as exc:  # not up yet
            last = exc
        time.sleep(0.1)
    raise RuntimeError(f"timed out after {timeout_s:.0f} s waiting for {what} ({last})")


# --- in-process fusion timing --------------------------------------------------------------------


@dataclass
class FusionTiming:
    sensors: int
    bodies: int
    steps: int
    fuse_step_ms: float
    fuse_step_p99_ms: float
    fuse_step_cpu_ms: float
    tracker_ms: float
    encode_json_ms: float
    handle_message_ms: float


def fusion_timing(sensors: int, bodies: int, steps: int = 1000, warmup: int = 100) -> FusionTiming:
    """Median cost of one fused frame (and of ingesting one frame) on the production classes."""
    from skelfuse.fusion.hub import FusionHub
    from skelfuse.fusion.pipeline import FusionPipeline
    from skelfuse.fusion.views import FusedPerson, View
    from skelfuse.protocol.feed import frame_json
    from skelfuse.server.broadcast import encode_message
    from skelfuse.server.settings import Settings

    tracker_times: list[float] = []

    class TimedPipeline(FusionPipeline):
        def update(self, views: list[View], t_s: float) -> list[FusedPerson]:
            start = time.perf_counter()
            out = super().update(views, t_s)
            tracker_times.append(time.perf_counter() - start)
            return out

    poses = sensor_layout(sensors)
    settings = Settings()
    calibration = Calibration(1, 0.0, {s: SensorCalibration(p, "bench") for s, p in poses.items()})
    hub = FusionHub(settings, calibration)
    hub.pipeline = TimedPipeline(settings.fusion)
    performer = ProceduralPerformer(bodies)
    states = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)
    t_start = math.floor(1_800_000_000.0 * FPS) / FPS
    ids = sorted(poses)
    for s in ids:
        hub.handle_message(s.encode(), [encode(_hello(s))], t_start, 0.0)
    sensor_from_world = {s: invert(poses[s]) for s in ids}
    fuse: list[float] = []
    fuse_cpu: list[float] = []
    encode_times: list[float] = []
    handle: list[float] = []
    for k in range(warmup + steps):
        t = t_start + k * PERIOD_S
        world = performer.joints_at(k * PERIOD_S)
        for j, s in enumerate(ids):
            phase = 0.002 + j * 0.004  # sensors out of phase, as real ones are
            bodies_ = tuple(
                Body(b + 1, apply(sensor_from_world[s], world[b]).astype(np.float32), states)
                for b in range(bodies)
            )
            payload = encode(Frame(k + 1, int((t + phase) * 1e9), bodies_))
            start = time.perf_counter()
            hub.handle_message(s.encode(), [payload], t + phase + 0.0005, k * PERIOD_S)
            handle.append(time.perf_counter() - start)
        start, start_cpu = time.perf_counter(), time.thread_time()
        fused = hub.fuse_step(t + PERIOD_S)
        elapsed, elapsed_cpu = time.perf_counter() - start, time.thread_time() - start_cpu
        if fused is None:
            raise RuntimeError(f"fusion produced nothing at step {k}")
        start = time.perf_counter()
        encode_message(frame_json(fused, False, time.time()), binary=False)
        encode_elapsed = time.perf_counter() - start
        if k >= warmup:
            fuse.append(elapsed)
            fuse_cpu.append(elapsed_cpu)
            encode_times.append(encode_elapsed)
    tracked = tracker_times[warmup:]
    return FusionTiming(
        sensors,
        bodies,
        steps,
        statistics.median(fuse) * 1e3,
        float(np.percentile(fuse, 99)) * 1e3,
        statistics.median(fuse_cpu) * 1e3,
        statistics.median(tracked) * 1e3,
        statistics.median(encode_times) * 1e3,
        statistics.median(handle[warmup * sensors :]) * 1e3,
    )


# --- reporting -----------------------------------------------------------------------------------


def median_result(runs: list[RunResult]) -> RunResult:
    """Field-wise median of several runs (counts: the worst run, so a loss is never hidden)."""
    out = RunResult(runs[0].config)
    worst = {"lost_frames", "sequence_gaps", "frames_rejected", "client_gaps_total",
             "client_gaps_max", "agent_drops_registered"}  # fmt: skip
    for name, value in asdict(runs[0]).items():
        if name in ("config", "notes"):
            continue
        values = [getattr(r, name) for r in runs]
        if name in worst:
            setattr(out, name, max(values))
        elif isinstance(value, int | float) or value is None:
            numbers = [v for v in values if v is not None and not math.isnan(v)]
            if numbers:
                median = statistics.median(numbers)
                setattr(out, name, type(value)(median) if isinstance(value, int) else median)
    out.notes = [n for r in runs for n in r.notes]
    out.rejected_reasons = {}
    for r in runs:
        for reason, n in r.rejected_reasons.items():
            out.rejected_reasons[reason] = max(n, out.rejected_reasons.get(reason, 0))
    return out


def ms(value: float) -> str:
    return "–" if math.isnan(value) else f"{value:.1f}"


def print_main(r: RunResult, repeat: int) -> None:
    c = r.config
    expected_ingest = c.agents * FPS
    evicted = "not evicted" if r.stalled_evicted_after_s is None else (
        f"evicted after {r.stalled_evicted_after_s:.1f} s"
    )  # fmt: skip
    rows = [
        ("frames sent by agents (whole run)", "—", f"{r.agent_frames_sent}"),
        ("frames received by the server (whole run)", "= sent", f"{r.server_frames_received}"),
        ("lost frames (sent − received)", "0", f"{r.lost_frames}"),
        ("agent-side drops while registered (HWM full)", "0", f"{r.agent_drops_registered}"),
        ("server `sequence_gaps`", "0", f"{r.sequence_gaps}"),
        ("server `frames_rejected` (by reason)", "0",
         f"{r.frames_rejected} {r.rejected_reasons or ''}"),
        ("agent frames dropped while not registered (incl. start-up)", "small",
         f"{r.agent_drops_unregistered}"),
        ("ingest rate (frames/s)", f"{expected_ingest:.0f}", f"{r.ingest_fps:.1f}"),
        ("fused output rate (frames/s)", "30 ± 1", f"{r.fused_fps:.2f}"),
        (f"per healthy client frames/s (min / median of {c.clients})", "30 ± 1",
         f"{r.client_fps_min:.2f} / {r.client_fps_median:.2f}"),
        ("gaps in `seq`, all healthy clients (max per client)", "0",
         f"{r.client_gaps_total} ({r.client_gaps_max})"),
        ("30 Hz grid instants never fused (median per client)", "0", f"{r.skipped_instants}"),
        ("latency capture→client, raw p50 / p99 / max (ms)", "—",
         f"{ms(r.latency_p50_ms)} / {ms(r.latency_p99_ms)} / {ms(r.latency_max_ms)}"),
        ("of which alignment wait p50 / p99 (ms)", "≤ 33 by design",
         f"{ms(r.wait_p50_ms)} / {ms(r.wait_p99_ms)}"),
        ("latency beyond the alignment wait p50 / p99 (ms)",
         f"≤ {TARGET_P50_MS:.0f} / ≤ {TARGET_P99_MS:.0f}",
         f"{ms(r.beyond_p50_ms)} / {ms(r.beyond_p99_ms)}"),
        ("server share `t_sent − t` p50 / p99 (ms)", "—",
         f"{ms(r.server_p50_ms)} / {ms(r.server_p99_ms)}"),
        ("server share beyond the wait p50 / p99 (ms)", "—",
         f"{ms(r.server_beyond_p50_ms)} / {ms(r.server_beyond_p99_ms)}"),
        ("healthy clients' p99 while the stalled one was connected / after (ms)",
         "unaffected", f"{ms(r.p99_while_stalled_ms)} / {ms(r.p99_after_evicted_ms)}"),
        ("stalled client", "evicted ≤ 10 s",
         f"{evicted}; {r.stalled_sent} sent, {r.stalled_dropped} dropped before"),
        ("server CPU (% of one core)", "—", f"{r.server_cpu_pct:.0f}"),
        ("server RSS start → end (max) (MB)", "growth < 10 %",
         f"{r.server_rss_start_mb:.0f} → {r.server_rss_end_mb:.0f} ({r.server_rss_max_mb:.0f})"),
        ("fused persons in the last frame", f"{c.bodies}", f"{r.persons_last}"),
    ]  # fmt: skip
    runs = f", median of {repeat} runs" if repeat > 1 else ""
    print(
        f"\n{c.agents} agents × {FPS:.0f} fps × {c.bodies} bodies, {c.clients} healthy WebSocket "
        f"clients + {c.stalled} stalled, {r.window_s:.0f} s window after {c.warmup_s:.0f} s "
        f"warm-up{runs}\n"
    )
    print("| metric | target | measured |")
    print("|---|---|---|")
    for name, target, value in rows:
        print(f"| {name} | {target} | {value} |")
    if r.agents_late:
        print(f"\nThe agents process fell behind its schedule {r.agents_late} times.")
    for note in dict.fromkeys(r.notes):
        print(f"\nNote: {note}")


def print_scaling(results: list[RunResult], repeat: int) -> None:
    runs = f" (median of {repeat} runs each)" if repeat > 1 else ""
    print(f"\nScaling{runs}: latency in ms; 'beyond' = beyond the alignment wait\n")
    print(
        "| agents | bodies | ingest/s (expected) | lost | seq gaps | fused/s | client gaps | "
        "instants skipped | "
        "raw p50 / p99 | wait p50 | beyond p50 / p99 | server beyond p50 / p99 | "
        "server CPU % | RSS MB | stalled evicted (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        c = r.config
        ev = "–" if r.stalled_evicted_after_s is None else f"{r.stalled_evicted_after_s:.1f}"
        print(
            f"| {c.agents} | {c.bodies} | {r.ingest_fps:.0f} ({c.agents * FPS:.0f}) | "
            f"{r.lost_frames} | {r.sequence_gaps} | {r.fused_fps:.1f} | {r.client_gaps_total} | "
            f"{r.skipped_instants} | "
            f"{ms(r.latency_p50_ms)} / {ms(r.latency_p99_ms)} | {ms(r.wait_p50_ms)} | "
            f"{ms(r.beyond_p50_ms)} / {ms(r.beyond_p99_ms)} | "
            f"{ms(r.server_beyond_p50_ms)} / {ms(r.server_beyond_p99_ms)} | "
            f"{r.server_cpu_pct:.0f} | {r.server_rss_end_mb:.0f} | {ev} |"
        )
    for note in dict.fromkeys(n for r in results for n in r.notes):
        print(f"\nNote: {note}")


def print_fusion(timings: list[FusionTiming]) -> None:
    print("\nIn-process fusion cost (production classes, simulated time), median over steps\n")
    print(
        "| sensors × bodies | `fuse_step` wall median (p99) ms | `fuse_step` CPU median ms "
        "| target | `FusionPipeline.update` wall ms | JSON encode per frame ms "
        "| `handle_message` per frame ms |"
    )
    print("|---|---|---|---|---|---|---|")
    for f in timings:
        target = f"≤ {TARGET_FUSE_MS:.0f}" if (f.sensors, f.bodies) == (4, 6) else "—"
        print(
            f"| {f.sensors} × {f.bodies} | {f.fuse_step_ms:.2f} ({f.fuse_step_p99_ms:.2f}) | "
            f"{f.fuse_step_cpu_ms:.2f} | {target} | {f.tracker_ms:.2f} | {f.encode_json_ms:.3f} | "
            f"{f.handle_message_ms:.3f} |"
        )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--agents", type=int, default=10)
    parser.add_argument("--bodies", type=int, default=6, choices=range(1, 7))
    parser.add_argument("--duration", type=float, default=120.0, help="measured window, s")
    parser.add_argument("--warmup", type=float, default=3.0, help="s after all sensors are online")
    parser.add_argument("--clients", type=int, default=20, help="healthy WebSocket clients")
    parser.add_argument("--stalled", type=int, default=1, choices=(0, 1), help="stalled clients")
    parser.add_argument("--scaling", action="store_true", help="agents 1..16 × bodies 1, 6")
    parser.add_argument("--scaling-duration", type=float, default=15.0)
    parser.add_argument("--repeat", type=int, default=1, help="runs per configuration (medians)")
    parser.add_argument("--fusion-only", action="store_true", help="in-process timing only")
    parser.add_argument("--fusion-steps", type=int, default=1000)
    parser.add_argument("--json", type=Path, default=None, help="write raw results here")
    args = parser.parse_args(argv)
    started = time.monotonic()
    log_dir = Path(tempfile.mkdtemp(prefix="skelfuse-load-logs-"))
    raw: dict[str, Any] = {}

    def run_config(config: RunConfig) -> RunResult:
        runs = []
        for k in range(args.repeat):
            print(
                f"  run {k + 1}/{args.repeat}: {config.agents} agents × {config.bodies} bodies, "
                f"{config.duration_s:.0f} s …",
                file=sys.stderr,
                flush=True,
            )
            runs.append(asyncio.run(run_once(config, seed=k + 1, log_dir=log_dir)))
        raw.setdefault("runs", []).extend(asdict(r) for r in runs)
        return median_result(runs)

    if not args.fusion_only:
        if args.scaling:
            configs = [
                RunConfig(a, b, args.scaling_duration, args.warmup, args.clients, args.stalled)
                for b in (1, 6)
                for a in (1, 2, 4, 8, 16)
            ]
            results = [run_config(config) for config in configs]
            print_scaling(results, args.repeat)
        else:
            config = RunConfig(args.agents, args.bodies, args.duration, args.warmup,
                               args.clients, args.stalled)  # fmt: skip
            print_main(run_config(config), args.repeat)
    timings = [fusion_timing(s, b, args.fusion_steps) for s, b in ((4, 6), (10, 6), (16, 6))]
    raw["fusion"] = [asdict(t) for t in timings]
    print_fusion(timings)
    print(
        f"\nMachine: {os.cpu_count()} cores, Python {sys.version.split()[0]}; "
        f"{time.monotonic() - started:.0f} s in all; server logs in {log_dir}"
    )
    if args.json:
        args.json.write_text(json.dumps(raw, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
