"""Many WebSocket viewers on one server: fused frames received, frames lost, age at receipt.

    python -m bench many_clients [--clients 500] [--processes 2] [--client websockets|raw]
                                 [--duration 30] [--runs 1]

Starts ``python -m skelfuse server`` on loopback (bench/live/server.py) with the load
benchmark's fake agents (bench/live/agents.py: ``--agents`` ZeroMQ agents at 30 fps seeing
``--bodies`` people, in a child process), then ``--clients`` WebSocket clients spread over
``--processes`` child processes, each an asyncio loop of ``websockets`` clients (or, with
``--client raw``, bench/live/clients.py's raw readers) reading the JSON feed as fast as it
comes. Over the measured window (after ``--warmup``) it reports:

- fused frames per second received per client (median and lowest over clients);
- frames lost per client: gaps in ``seq`` between consecutive frames a client received (the
  feed conflates, so a client that does not keep up loses frames; one that keeps up loses none);
- age at receipt, p50 / p99 over every frame of every client: receive time minus ``t_sent``
  (the server's publish time: what fan-out and the network add) and minus ``t`` (the fused
  instant: what alignment, fusion and fan-out add);
- the server's own share of that age, from its ``send`` stage (``server/stage_timing.py``):
  ``t_sent`` to the frame's write into each client's socket, p50 / p99 over client-frames, and
  its ``publish`` stage (the whole fan-out of one frame to the clients ready for it). What the
  clients measure above that is the kernel's delivery and the clients' own scheduling: on one
  machine they share its cores with the server, which ``--processes`` spreads over;
- the server's CPU (% of one core), how long its event loop waited for a CPU while it had work
  (% of the window: a starved server on a shared machine), RSS (start, max, end), the clients'
  CPU, the server's ``conflated`` and ``evicted`` counts, and the load average before and after.

Clients only look at the start of each message (``seq``, ``t`` and ``t_sent`` come first in a
frame message, docs/api.md): parsing whole frames 15,000 times a second would measure the
clients' JSON parser, not the server.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing as mp
import os
import re
import statistics
import sys
import time
from array import array
from collections.abc import Callable
from multiprocessing.synchronize import Event as MpEvent
from pathlib import Path
from typing import Any

from bench.live.agents import agents_process, sensor_layout
from bench.live.clients import FeedTally, raw_client
from bench.live.server import (
    free_port,
    http_json,
    proc_cpu_s,
    proc_rss_mb,
    start_server,
    wait_for,
)
from bench.live.stages import scrape_stages, window_quantile

HEAD = re.compile(r'"seq":(\d+),"t":([0-9.eE+-]+),"t_sent":([0-9.eE+-]+)')


async def _client(url: str, measuring: asyncio.Event, stopping: asyncio.Event) -> dict[str, Any]:
    """One viewer: counts frames, seq gaps and ages while ``measuring`` and not ``stopping``.

    A handshake that fails before the window (a busy server, 500 at once) is tried again.
    """
    from websockets.asyncio.client import connect

    tally = FeedTally()
    out = tally.out
    while not stopping.is_set():
        try:
            async with connect(url, compression=None, max_size=2**22, open_timeout=30) as ws:
                await ws.recv()  # the skeleton definition
                out["error"] = None
                while not stopping.is_set():
                    message = await ws.recv()
                    received = time.time()
                    head = HEAD.search(message[:200] if isinstance(message, str) else "")
                    if head is not None and measuring.is_set():
                        tally.count(head, received)
        except Exception as exc:  # reported; before the window, connect again
            out["error"] = f"{type(exc).__name__}: {exc}"
            if measuring.is_set() or out["frames"]:
                break
            out["retries"] += 1
            await asyncio.sleep(1.0)
    return tally.result()


def clients_process(
    url: str,
    count: int,
    start: MpEvent,
    stop: MpEvent,
    results: mp.Queue[Any],
    kind: str = "websockets",
) -> None:
    """Run ``count`` clients (``kind``: ``websockets`` or ``raw``) in one asyncio loop; measure
    between ``start`` and ``stop``."""
    client = raw_client if kind == "raw" else _client

    async def main() -> list[dict[str, Any]]:
        measuring, stopping = asyncio.Event(), asyncio.Event()
        tasks = []
        for _ in range(count):  # connect gradually: 500 handshakes at once time out
            tasks.append(asyncio.create_task(client(url, measuring, stopping)))
            await asyncio.sleep(0.005)
        await asyncio.to_thread(start.wait)
        measuring.set()
        await asyncio.to_thread(stop.wait)
        measuring.clear()
        stopping.set()
        done, pending = await asyncio.wait(tasks, timeout=10)
        for task in pending:
            task.cancel()
        return [task.result() for task in done if not task.cancelled()]

    started = time.process_time()
    # uvloop (the server's loop too, where installed): a read costs the clients far less.
    try:
        import uvloop

        loop_factory: Callable[[], asyncio.AbstractEventLoop] | None = uvloop.new_event_loop
    except ImportError:
        loop_factory = None
    with asyncio.Runner(loop_factory=loop_factory) as runner:
        logs = runner.run(main())
    results.put({"clients": logs, "cpu_s": time.process_time() - started})


def runqueue_wait_s(pid: int) -> float:
    """Seconds the process's main thread (the server's event loop) has waited for a CPU while
    runnable (Linux ``/proc/<pid>/schedstat``): on a shared machine, the share of the window
    it was starved."""
    return int(Path(f"/proc/{pid}/schedstat").read_text().split()[1]) / 1e9


def _rounded(value_ms: float) -> float | None:
    return None if value_ms != value_ms else round(value_ms, 2)


def _pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q / 100 * len(ordered)))]


def _wait_connected(base: str, clients: int, agents: int, timeout_s: float = 180.0) -> None:
    """Poll until every client is connected and every sensor online (progress on stderr).

    Raises:
        RuntimeError: not so after ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    health: dict[str, Any] = {}
    while time.monotonic() < deadline:
        try:
            health = http_json(base + "/api/health", timeout_s=15.0)
        except OSError as exc:  # a busy server: try again
            print(f"health: {exc}", file=sys.stderr)
            continue
        if health["ws_clients"] >= clients and health["sensors_online"] == agents:
            return
        online = health["sensors_online"]
        print(f"{health['ws_clients']} clients, {online} sensors", file=sys.stderr)
        time.sleep(2.0)
    raise RuntimeError(f"clients or sensors missing after {timeout_s:.0f} s: {health}")


def run_once(args: argparse.Namespace, seed: int, log_dir: Path) -> dict[str, Any]:
    """One server, its agents and its clients; the window's figures.

    Raises:
        RuntimeError: the server did not start or never fused.
    """
    http_port, zmq_port = free_port(), free_port()
    base = f"http://127.0.0.1:{http_port}"
    poses = sensor_layout(args.agents)
    server, log_file = start_server(poses, http_port, zmq_port, log_dir / f"server-{seed}.log")
    ctx = mp.get_context("spawn")
    stop_agents, start, stop = ctx.Event(), ctx.Event(), ctx.Event()
    agent_results: mp.Queue[Any] = ctx.Queue()
    client_results: mp.Queue[Any] = ctx.Queue()
    children: list[mp.process.BaseProcess] = []
    try:
        # 60 s: on a busy machine, numba's cache load alone has taken 20 s
        wait_for(lambda: http_json(base + "/api/health"), 60, "the server to start")
        agents = ctx.Process(
            target=agents_process,
            args=(
                f"tcp://127.0.0.1:{zmq_port}",
                {s: [float(x) for x in p.reshape(16)] for s, p in poses.items()},
                args.bodies, seed, args.warmup + args.duration + 600.0, stop_agents,
                agent_results,
            ),
            daemon=True,
        )  # fmt: skip
        agents.start()
        children.append(agents)
        url = f"ws://127.0.0.1:{http_port}/ws/skeletons"
        shares = [args.clients // args.processes] * args.processes
        shares[0] += args.clients - sum(shares)
        shares = [share for share in shares if share]  # --clients 0: the server alone
        for share in shares:
            child = ctx.Process(
                target=clients_process,
                args=(url, share, start, stop, client_results, args.client),
                daemon=True,
            )
            child.start()
            children.append(child)
        _wait_connected(base, args.clients, args.agents)
        time.sleep(args.warmup)
        window = _measure(base, server.pid, args.duration, start, stop)
        logs: list[dict[str, Any]] = []
        clients_cpu = 0.0
        for _ in shares:
            part = client_results.get(True, 60)
            logs.extend(part["clients"])
            clients_cpu += part["cpu_s"]
    finally:
        stop_agents.set()
        start.set()
        stop.set()
        for process in children:
            process.join(5)
            if process.is_alive():
                process.kill()
        server.send_signal(2)
        try:
            server.wait(15)
        except Exception:
            server.kill()
        log_file.close()
    return _figures(window, logs, clients_cpu)


def _measure(
    base: str, pid: int, duration_s: float, start: MpEvent, stop: MpEvent
) -> dict[str, Any]:
    """Let the clients count for ``duration_s``, then stop them; the server's figures at the
    window's two ends (``<name>0`` and ``<name>1``; times s since the epoch, CPU s, RSS MB)."""
    load_before = os.getloadavg()
    fused0 = http_json(base + "/api/health")["fused_frames"]
    rss_start = proc_rss_mb(pid)
    rss_max = rss_start
    stages0 = scrape_stages(base)
    conflated0 = {c["id"]: int(c["conflated"]) for c in http_json(base + "/api/clients")["clients"]}
    t0, cpu0, wait0 = time.time(), proc_cpu_s(pid), runqueue_wait_s(pid)
    start.set()
    while time.time() < t0 + duration_s:
        time.sleep(1.0)
        rss_max = max(rss_max, proc_rss_mb(pid))
    # The server's figures before the clients stop (then they leave, with their counts).
    t1, cpu1, wait1 = time.time(), proc_cpu_s(pid), runqueue_wait_s(pid)
    stages1 = scrape_stages(base)
    fused1 = http_json(base + "/api/health")["fused_frames"]
    clients_now = http_json(base + "/api/clients")
    stop.set()
    rss_end = proc_rss_mb(pid)
    load_after = os.getloadavg()
    return {
        "t0": t0, "t1": t1, "cpu0": cpu0, "cpu1": cpu1, "wait0": wait0, "wait1": wait1,
        "fused0": fused0, "fused1": fused1, "stages0": stages0, "stages1": stages1,
        "conflated0": conflated0, "clients_now": clients_now,
        "rss": (rss_start, rss_max, rss_end), "load": (load_before, load_after),
    }  # fmt: skip


def _figures(m: dict[str, Any], logs: list[dict[str, Any]], clients_cpu: float) -> dict[str, Any]:
    """The run's figures from the server's (``_measure``) and the clients' (``logs``, their
    CPU time ``clients_cpu`` in s)."""
    window = m["t1"] - m["t0"]
    ages_sent: list[float] = []
    ages_t: list[float] = []
    for log in logs:
        ages_sent.extend(array("d", log["ages_sent"]))
        ages_t.extend(array("d", log["ages_t"]))
    fps = [log["frames"] / window for log in logs]
    lost = [int(log["lost"]) for log in logs]
    errors = [log["error"] for log in logs if log["error"]]
    rss_start, rss_max, rss_end = m["rss"]
    load_before, load_after = m["load"]
    return {
        "clients": len(logs),
        "window_s": round(window, 2),
        "fused_fps_server": round((m["fused1"] - m["fused0"]) / window, 2),
        "fps_received_median": round(statistics.median(fps), 2) if fps else None,
        "fps_received_min": round(min(fps), 2) if fps else None,
        "lost_total": sum(lost),
        "clients_with_loss": sum(1 for n in lost if n),
        "lost_max_per_client": max(lost, default=0),
        "age_sent_p50_ms": round(1000 * _pct(ages_sent, 50), 1),
        "age_sent_p99_ms": round(1000 * _pct(ages_sent, 99), 1),
        "age_t_p50_ms": round(1000 * _pct(ages_t, 50), 1),
        "age_t_p99_ms": round(1000 * _pct(ages_t, 99), 1),
        # NaN (a server without the stage): JSON null.
        **{
            f"server_{stage}_p{q}_ms": _rounded(
                window_quantile(m["stages0"].get(stage), m["stages1"].get(stage), q / 100)
            )
            for stage in ("send", "publish")
            for q in (50, 99)
        },
        "server_cpu_pct": round(100 * (m["cpu1"] - m["cpu0"]) / window, 1),
        "server_loop_runqueue_wait_pct": round(100 * (m["wait1"] - m["wait0"]) / window, 1),
        "clients_cpu_pct": round(100 * clients_cpu / window, 1),
        "server_rss_mb": [round(rss_start, 1), round(rss_max, 1), round(rss_end, 1)],
        "conflated_total": sum(  # in the window
            int(c["conflated"]) - m["conflated0"].get(c["id"], 0)
            for c in m["clients_now"]["clients"]
        ),
        "evicted": int(m["clients_now"]["evicted"]),
        "client_errors": errors[:5],
        "client_error_count": len(errors),
        "handshake_retries": sum(int(log["retries"]) for log in logs),
        "loadavg_before": [round(x, 2) for x in load_before],
        "loadavg_after": [round(x, 2) for x in load_after],
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark ``--runs`` times; print each run's figures as one JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clients", type=int, default=500)
    parser.add_argument("--processes", type=int, default=2, help="client processes")
    parser.add_argument(
        "--client",
        choices=("websockets", "raw"),
        default="websockets",
        help="websockets: the library's client; raw: bench/live/clients.py's RawFeedReader, "
        "the least work per message (the clients' own share of the ages, compared)",
    )
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--bodies", type=int, default=6)
    parser.add_argument("--duration", type=float, default=30.0, help="measured seconds")
    parser.add_argument("--warmup", type=float, default=5.0)
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument("--logs", default="artifacts/many_clients", help="server logs go here")
    args = parser.parse_args(argv)
    log_dir = Path(args.logs)
    log_dir.mkdir(parents=True, exist_ok=True)
    for seed in range(1, args.runs + 1):
        print(json.dumps(run_once(args, seed, log_dir)), flush=True)
    return 0
