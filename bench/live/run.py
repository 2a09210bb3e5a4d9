"""One load run: the server, the agents and the clients together, measured over one window."""

from __future__ import annotations

import asyncio
import math
import multiprocessing as mp
import socket
import statistics
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.synchronize import Event as MpEvent
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from bench.live.agents import FPS, agents_process, sensor_layout
from bench.live.calibrate import calibrate_under_load
from bench.live.clients import (
    ClientLog,
    healthy_client,
    open_stalled_client,
    raw_healthy_client,
)
from bench.live.server import (
    free_port,
    get,
    http_json,
    proc_cpu_s,
    proc_rss_mb,
    start_server,
    wait_for,
)
from bench.live.stages import Buckets, scrape_stages, window_quantile
from bench.live.waits import OffsetSeries, alignment_waits, offset_series
from skelfuse.protocol.transform import Matrix4

FloatArray = npt.NDArray[np.float64]


@dataclass
class RunConfig:
    """One configuration: agents × bodies, the measured window and warm-up (s), the clients."""

    agents: int
    bodies: int
    duration_s: float
    warmup_s: float = 3.0
    clients: int = 20
    stalled: int = 1
    calibrate: str | None = None
    """A calibration method (``auto``) run through REST part-way into the window, or None."""
    calibrate_capture_s: float = 15.0
    client: str = "websockets"
    """The healthy clients: ``websockets`` (parse every frame) or ``raw`` (time the bytes'
    arrival, read the head; :func:`bench.live.clients.raw_healthy_client`)."""


@dataclass
class RunResult:
    """Everything one run measured (latencies in ms, rates per second, memory in MB)."""

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
    send_p50_ms: float = math.nan
    """``t_sent`` → client receive (build, encode, queue, send, the client's decode)."""
    send_p99_ms: float = math.nan
    ingest_p50_ms: float = math.nan
    """The server's stage histograms over the window (``server/stage_timing.py``): ingest
    per agent message, fusion step and publish per fused frame, lag = fusion start − ``t``."""
    ingest_p99_ms: float = math.nan
    fusion_p50_ms: float = math.nan
    fusion_p99_ms: float = math.nan
    publish_p50_ms: float = math.nan
    publish_p99_ms: float = math.nan
    lag_p50_ms: float = math.nan
    lag_p99_ms: float = math.nan
    calibration_state: str = ""
    """With ``calibrate``: how the run ended, its length (s), the event loop's longest and p99
    stall (ms), ticks over 20 ms, the agents' "server silent" lines while it ran, and the loop's
    longest and p99 stall in the window before it (the load alone)."""
    calibration_s: float = math.nan
    calibration_lag_max_ms: float = math.nan
    calibration_lag_p99_ms: float = math.nan
    calibration_over_20ms: int = 0
    calibration_server_silent: int = 0
    calibration_icp: int = 0
    baseline_lag_max_ms: float = math.nan
    baseline_lag_p99_ms: float = math.nan
    baseline_over_20ms: int = 0
    baseline_s: float = math.nan
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
    alignment: str = ""
    """The server's alignment policy (``/api/fusion/settings``): the reconstructed wait is
    that of ``aligned`` / ``phased``, which wait for every sensor."""
    notes: list[str] = field(default_factory=list)


def _pct(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile of ``values`` (s) in ms; NaN when there are none."""
    return float(np.percentile(np.asarray(values), q)) * 1e3 if len(values) else math.nan


def stage_figures(result: RunResult, before: dict[str, Buckets], after: dict[str, Buckets]) -> None:
    """Set ``result``'s server stage p50 / p99 from two scrapes of the stage histograms."""
    for stage in ("ingest", "fusion", "publish", "lag"):
        for q in (50, 99):
            value = window_quantile(before.get(stage), after.get(stage), q / 100)
            setattr(result, f"{stage}_p{q}_ms", value)
    if not after:
        result.notes.append("the server's /metrics has no skelfuse_live_stage_seconds")


async def run_once(config: RunConfig, seed: int, log_dir: Path) -> RunResult:
    """Start the server, the agents and the clients, measure one window, stop them all.

    Raises:
        RuntimeError: the server did not start, or the sensors never came online.
    """
    result = RunResult(config)
    http_port, zmq_port = free_port(), free_port()
    base = f"http://127.0.0.1:{http_port}"
    poses = sensor_layout(config.agents)
    log_path = log_dir / f"server-{config.agents}x{config.bodies}-{seed}.log"
    server, log_file = start_server(poses, http_port, zmq_port, log_path)
    ctx = mp.get_context("spawn")
    load = _Load(ctx.Event(), ctx.Queue())
    agents_log = log_dir / f"agents-{config.agents}x{config.bodies}-{seed}.log"
    try:
        await asyncio.to_thread(
            wait_for, lambda: http_json(base + "/api/health"), 20, "the server to start"
        )
        await _start_load(load, config, seed, http_port, zmq_port, poses, agents_log)
        online_s = 30 if config.calibrate is None else 30 + 2 * config.agents  # depth renders
        await asyncio.to_thread(
            wait_for, lambda: _all_online(base, config.agents), online_s,
            "every sensor online and fusing",
        )  # fmt: skip
        settings = await asyncio.to_thread(http_json, base + "/api/fusion/settings")
        result.alignment = str(settings["fusion"]["alignment"]["policy"])
        await asyncio.sleep(config.warmup_s)
        window = await _measure(result, config, base, server.pid, load, agents_log)
        if load.calibration is not None:
            await _calibration_figures(result, config, load)
        load.stop.set()
        agent_out: dict[str, Any] = await asyncio.to_thread(load.queue.get, True, 30)
        assert load.agents is not None
        await asyncio.to_thread(load.agents.join, 10)
        await asyncio.sleep(0.5)  # the last frames in flight
        sensors_end = await get(base + "/api/sensors")
    finally:
        await _stop(load, server, log_file)
    offsets, captures = _ingest_figures(result, window, agent_out, sensors_end)
    _client_figures(result, window, load.logs, captures, offsets)
    _stalled_figures(result, window, load.stalled)
    return result


@dataclass
class _Load:
    """What a run starts beside the server: the clients, the agents' process, a calibration."""

    stop: MpEvent
    """Tells the agents' process to stop."""
    queue: mp.Queue[Any]
    """Where the agents' process puts its figures when stopped."""
    logs: list[ClientLog] = field(default_factory=list)
    tasks: list[asyncio.Task[None]] = field(default_factory=list)
    stalled: list[tuple[socket.socket, int, float]] = field(default_factory=list)
    """Each stalled client's socket, local port and connection time (s since the epoch)."""
    agents: mp.process.BaseProcess | None = None
    calibration: asyncio.Task[Any] | None = None


@dataclass
class _Window:
    """The measured window: its ends (s since the epoch), the server's REST answers at each
    end, its stage histograms, its clock offsets through it, and what became of the stalled
    clients (last ``/api/clients`` entry, and when it vanished, by local port)."""

    t0: float
    t1: float
    sensors0: dict[str, Any]
    sensors1: dict[str, Any]
    health0: dict[str, Any]
    health1: dict[str, Any]
    stages0: dict[str, Buckets]
    stages1: dict[str, Buckets]
    offset_samples: list[tuple[float, dict[str, Any]]]
    stalled_seen: dict[int, dict[str, Any]]
    evicted_at: dict[int, float]


async def _start_load(
    load: _Load,
    config: RunConfig,
    seed: int,
    http_port: int,
    zmq_port: int,
    poses: dict[str, Matrix4],
    agents_log: Path,
) -> None:
    """Connect the healthy and the stalled clients, then start the agents' process."""
    load.logs = [ClientLog() for _ in range(config.clients)]
    ws_url = f"ws://127.0.0.1:{http_port}/ws/skeletons"
    reader = raw_healthy_client if config.client == "raw" else healthy_client
    load.tasks = [asyncio.create_task(reader(ws_url, log)) for log in load.logs]
    for _ in range(config.stalled):
        sock, port = await asyncio.to_thread(open_stalled_client, http_port)
        load.stalled.append((sock, port, time.time()))
    load.agents = mp.get_context("spawn").Process(
        target=agents_process,
        args=(
            f"tcp://127.0.0.1:{zmq_port}",
            {s: [float(x) for x in p.reshape(16)] for s, p in poses.items()},
            config.bodies, seed, config.warmup_s + config.duration_s + 180.0, load.stop,
            load.queue, str(agents_log), config.calibrate is not None,
        ),
        daemon=True,
    )  # fmt: skip
    load.agents.start()


def _all_online(base: str, agents: int) -> bool:
    health = http_json(base + "/api/health")
    return bool(health["sensors_online"] == agents and health["fused_frames"] > 30)


async def _snapshot(base: str, pid: int) -> tuple[float, float, dict[str, Any], dict[str, Any]]:
    """Now (s since the epoch), the server's CPU time (s), ``/api/sensors``, ``/api/health``."""
    t = time.time()
    cpu = proc_cpu_s(pid)
    sensors, health = await asyncio.gather(get(base + "/api/sensors"), get(base + "/api/health"))
    return t, cpu, sensors, health


async def _measure(
    result: RunResult, config: RunConfig, base: str, pid: int, load: _Load, agents_log: Path
) -> _Window:
    """Poll the server through the window (starting the calibration part-way, if any); set
    ``result``'s CPU, memory, persons and eviction figures."""
    stages0 = await asyncio.to_thread(scrape_stages, base)
    t0, cpu0, sensors0, health0 = await _snapshot(base, pid)
    # The server maps each frame with its clock offset estimate of the moment: sample them
    # through the run for the alignment-wait reconstruction (bench/live/waits.py).
    offset_samples = [(t0, {s["id"]: s["clock_offset_s"] for s in sensors0["sensors"]})]
    result.server_rss_start_mb = proc_rss_mb(pid)
    rss_max = result.server_rss_start_mb
    stalled_seen: dict[int, dict[str, Any]] = {}
    evicted_at: dict[int, float] = {}
    end = t0 + config.duration_s
    if config.calibrate is not None:  # starts a fifth into the window, after a baseline
        load.calibration = asyncio.create_task(calibrate_under_load(
            base, config.calibrate, config.calibrate_capture_s, config.duration_s / 5,
            [agents_log],
        ))  # fmt: skip
    while (now := time.time()) < end:
        await asyncio.sleep(min(1.0, end - now))
        rss_max = max(rss_max, proc_rss_mb(pid))
        clients, sensors = await asyncio.gather(
            get(base + "/api/clients"), get(base + "/api/sensors")
        )
        offset_samples.append(
            (time.time(), {s["id"]: s["clock_offset_s"] for s in sensors["sensors"]})
        )
        for _, port, _ in load.stalled:
            entry = next(
                (c for c in clients["clients"] if str(c["remote"]).endswith(f"{port})")), None
            )
            if entry is not None:
                stalled_seen[port] = entry
            elif port not in evicted_at:
                evicted_at[port] = time.time()
    t1, cpu1, sensors1, health1 = await _snapshot(base, pid)
    stages1 = await asyncio.to_thread(scrape_stages, base)
    result.server_rss_end_mb = proc_rss_mb(pid)
    result.server_rss_max_mb = max(rss_max, result.server_rss_end_mb)
    result.window_s = t1 - t0
    result.server_cpu_pct = 100 * (cpu1 - cpu0) / result.window_s
    result.persons_last = int(health1["persons"])
    result.evicted_total = int((await get(base + "/api/clients"))["evicted"])
    return _Window(
        t0, t1, sensors0, sensors1, health0, health1, stages0, stages1,
        offset_samples, stalled_seen, evicted_at,
    )  # fmt: skip


async def _calibration_figures(result: RunResult, config: RunConfig, load: _Load) -> None:
    """Wait for the calibration run under load and set its figures (or a note why none)."""
    assert load.calibration is not None
    try:
        baseline, calibrated = await asyncio.wait_for(load.calibration, 300)
    except Exception as exc:  # e.g. refused with a 409: the load figures still stand
        result.notes.append(f"the calibration did not run: {type(exc).__name__}: {exc}")
        load.calibration = None
        return
    result.calibration_state = calibrated.state + ("" if calibrated.icp_applied else
                                                   " (no ICP)")  # fmt: skip
    result.calibration_s = calibrated.seconds
    result.calibration_lag_max_ms = calibrated.max_ms
    result.calibration_lag_p99_ms = calibrated.p99_ms
    result.calibration_over_20ms = calibrated.over_20ms
    result.calibration_server_silent = calibrated.server_silent
    result.calibration_icp = int(calibrated.icp_applied)
    result.baseline_lag_max_ms = baseline.max_ms
    result.baseline_lag_p99_ms = baseline.p99_ms
    result.baseline_over_20ms = baseline.over_20ms
    result.baseline_s = baseline.seconds
    if calibrated.seconds > config.duration_s * 0.8:
        result.notes.append("the calibration ran past the window's end")


async def _stop(load: _Load, server: subprocess.Popen[bytes], log_file: IO[bytes]) -> None:
    """Stop everything the run started, the server last (SIGINT, then killed after 15 s)."""
    load.stop.set()
    if load.calibration is not None and not load.calibration.done():
        load.calibration.cancel()
    for task in load.tasks:
        task.cancel()
    await asyncio.gather(*load.tasks, return_exceptions=True)
    for sock, _, _ in load.stalled:
        sock.close()
    if load.agents is not None and load.agents.is_alive():
        load.agents.kill()
    server.send_signal(2)
    try:
        server.wait(timeout=15)
    except subprocess.TimeoutExpired:
        server.kill()
        server.wait()
    log_file.close()


def _ingest_figures(
    result: RunResult, window: _Window, agent_out: dict[str, Any], sensors_end: dict[str, Any]
) -> tuple[dict[str, OffsetSeries], dict[str, FloatArray]]:
    """Set what the agents sent and the server received, rejected and fused. Returns the
    clock offsets through the window (``offset_series``) and each sensor's capture times."""
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
    rx0 = sum(s["frames_received"] for s in window.sensors0["sensors"])
    rx1 = sum(s["frames_received"] for s in window.sensors1["sensors"])
    result.ingest_fps = (rx1 - rx0) / result.window_s
    fused = window.health1["fused_frames"] - window.health0["fused_frames"]
    result.fused_fps = fused / result.window_s
    window.offset_samples.append(
        (window.t1, {s["id"]: s["clock_offset_s"] for s in window.sensors1["sensors"]})
    )
    offsets = offset_series(window.offset_samples)
    captures = {s: np.asarray(a["captures"], dtype=np.float64) for s, a in per_agent.items()}
    return offsets, captures


def _client_figures(
    result: RunResult,
    window: _Window,
    logs: list[ClientLog],
    captures: dict[str, FloatArray],
    offsets: dict[str, OffsetSeries],
) -> None:
    """Set the healthy clients' rates, gaps and latencies over the window (and how much of
    the latency is the alignment wait), and the server's stage figures."""
    fps: list[float] = []
    gaps: list[int] = []
    skipped: list[int] = []
    latency: list[float] = []
    server_share: list[float] = []
    beyond: list[float] = []
    server_beyond: list[float] = []
    send: list[float] = []
    waits_all: list[float] = []
    evicted = min(window.evicted_at.values()) if window.evicted_at else None
    stalled_lat: list[float] = []
    after_lat: list[float] = []
    for log in logs:
        if log.error:
            result.notes.append(f"a healthy client failed: {log.error}")
        rows = np.asarray(
            [r for r in log.records if window.t0 <= r[0] <= window.t1], dtype=np.float64
        )
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
        send.extend(rows[:, 0] - rows[:, 3])
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
    result.send_p50_ms = _pct(send, 50)
    result.send_p99_ms = _pct(send, 99)
    stage_figures(result, window.stages0, window.stages1)
    result.p99_after_evicted_ms = _pct(after_lat, 99)


def _stalled_figures(
    result: RunResult, window: _Window, stalled: list[tuple[socket.socket, int, float]]
) -> None:
    """Set when the first stalled client was evicted and what it was sent and dropped."""
    if stalled:
        _, port, connected = stalled[0]
        if port in window.evicted_at:
            result.stalled_evicted_after_s = window.evicted_at[port] - connected
        last = window.stalled_seen.get(port)
        if last is not None:
            result.stalled_sent = int(last["sent"])
            result.stalled_dropped = int(last["dropped"])
        elif port not in window.evicted_at:
            result.notes.append("the stalled client never appeared in /api/clients")
