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
  computes that wait for each fused frame (``bench/live/waits.py``: the capture time of the last
  frame the instant needed, mapped onto the server's clock with the offset estimates sampled
  through the run, minus ``t``) and also reports the latency beyond it;
- per stage of the live path (``stages``): the exact alignment wait above; the server's own
  histograms ``skelfuse_live_stage_seconds`` over the window (ingest per agent message, fusion
  step and publish per fused frame, fusion start − ``t``); ``t_sent`` → client receive; p50 / p99
  of each;
- server CPU (% of one core) and RSS from ``/proc/<pid>`` (Linux);
- the stalled client: when it was evicted (``GET /api/clients``), frames sent to / dropped for
  it, and the healthy clients' latency while it was connected vs after.

Separately, in-process (BLAS pinned to one thread, as in ``skelfuse server``): the fusion
compute per fused frame (``FusionHub.fuse_step`` and the ``FusionPipeline.update`` inside it, and
per pipeline stage: ``fusion_stages``), the per-frame JSON encode, and ``handle_message`` per
incoming frame, median over 1000 steps; and the feed message alone (build, encode) for 6
people, median over 5000 runs; and ``decode`` of one incoming 6-body frame, median over 5000
runs.

Run: ``python -m bench load`` (main run: 10 agents × 6 bodies, 120 s), ``--scaling`` (agents in
1, 2, 4, 8, 16 × bodies in 1, 6, 15 s each), ``--repeat K`` (K runs per configuration, medians
reported), ``--agents``, ``--bodies``, ``--duration``, ``--clients``, ``--stalled``,
``--fusion-only`` (the in-process timing only), ``--encode-only`` (the feed message only),
``--decode-only`` (decoding one incoming frame only),
``--calibrate auto`` (a full calibration through REST a fifth into the main run's window: the
event loop's longest / p99 stall while it runs, against the window before it, and the agents'
"server silent" lines; ``--calibrate-capture`` s of skeleton capture; skeleton calibration
needs one person in view, so ``auto`` with ``--bodies 1``, or ``icp`` with more bodies),
``--json FILE`` (raw results).

The parts: ``agents`` (the fake agents), ``clients`` (the WebSocket clients),
``server`` (the server subprocess), ``run`` (one run and its figures),
``fusion_timing`` (the in-process timing), ``encode`` (the feed message),
``decode`` (decoding a frame), ``stages`` (the server's stage histograms),
``calibrate`` (the calibration under load),
``report`` (the tables).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from bench.live.decode import decode_timing, print_decode
from bench.live.encode import encode_timing, print_encode
from bench.live.fusion_timing import fusion_timing
from bench.live.host_speed import host_speed
from bench.live.report import median_result, print_fusion, print_main, print_scaling
from bench.live.run import RunConfig, RunResult, run_once
from skelfuse.blas import pin_blas_threads


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the command line, run what it asks for, print the tables; returns the exit status."""
    args = _parser().parse_args(argv)
    pin_blas_threads()  # the in-process timings run as the server does
    started = time.monotonic()
    log_dir = Path(tempfile.mkdtemp(prefix="skelfuse-load-logs-"))
    raw: dict[str, Any] = {}
    decodes = [decode_timing(bodies=6, not_tracked=nt) for nt in (False, True)]
    raw["decode"] = [asdict(d) for d in decodes]
    if args.decode_only:
        print_decode(decodes)
        return 0
    encode = encode_timing(bodies=6)
    raw["encode"] = asdict(encode)
    if args.encode_only:
        print_encode(encode)
        return 0
    if not args.fusion_only:
        _live_runs(args, log_dir, raw)
    speeds = [host_speed()]  # the host's state before and after (bench/live/host_speed.py)
    timings = [
        fusion_timing(s, b, args.fusion_steps, drive=args.fusion_drive)
        for s, b in ((4, 6), (10, 6), (16, 6))
    ]
    speeds.append(host_speed())
    raw["fusion"] = [asdict(t) for t in timings]
    raw["host_speed"] = [asdict(speed) for speed in speeds]
    print_fusion(timings, speeds)
    print_encode(encode)
    print_decode(decodes)
    print(
        f"\nMachine: {os.cpu_count()} cores, Python {sys.version.split()[0]}; "
        f"{time.monotonic() - started:.0f} s in all; server logs in {log_dir}"
    )
    if args.json:
        args.json.write_text(json.dumps(raw, indent=1, default=str))
    return 0


def _parser() -> argparse.ArgumentParser:
    """The command line: the live run's configuration, the scaling sweep, the in-process parts."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    parser.add_argument("--agents", type=int, default=10)
    parser.add_argument("--bodies", type=int, default=6, choices=range(1, 7))
    parser.add_argument("--duration", type=float, default=120.0, help="measured window, s")
    parser.add_argument("--warmup", type=float, default=3.0, help="s after all sensors are online")
    parser.add_argument("--clients", type=int, default=20, help="healthy WebSocket clients")
    parser.add_argument("--stalled", type=int, default=1, choices=(0, 1), help="stalled clients")
    parser.add_argument(
        "--client", choices=("websockets", "raw"), default="websockets",
        help="the healthy clients: the websockets library parsing every frame's JSON, or a raw "
        "reader timing each frame when its bytes arrive and reading only its head",
    )  # fmt: skip
    parser.add_argument("--scaling", action="store_true", help="agents 1..16 × bodies 1, 6")
    parser.add_argument("--scaling-duration", type=float, default=15.0)
    parser.add_argument("--repeat", type=int, default=1, help="runs per configuration (medians)")
    parser.add_argument("--fusion-only", action="store_true", help="in-process timing only")
    parser.add_argument("--fusion-steps", type=int, default=1000)
    parser.add_argument(
        "--fusion-drive", choices=("arrivals", "period"), default="arrivals",
        help="in-process timing: fuse_step at each arrival and deadline, as the live loop does, "
        "or once per period (before 2026-11-23 16:00: every sensor carried, the late worst case)",
    )  # fmt: skip
    parser.add_argument("--encode-only", action="store_true", help="the feed message cost only")
    parser.add_argument("--decode-only", action="store_true", help="decoding one frame only")
    parser.add_argument("--json", type=Path, default=None, help="write raw results here")
    parser.add_argument(
        "--calibrate", choices=("auto", "skeleton", "icp"), default=None,
        help="run this calibration through REST a fifth into the window: loop lag, 'server silent'",
    )  # fmt: skip
    parser.add_argument("--calibrate-capture", type=float, default=15.0, help="skeleton capture, s")
    return parser


def _live_runs(args: argparse.Namespace, log_dir: Path, raw: dict[str, Any]) -> None:
    """The live runs (the scaling sweep, or the one configuration asked for), their table
    printed and their raw results added to ``raw["runs"]``."""
    if args.scaling:
        configs = [
            RunConfig(a, b, args.scaling_duration, args.warmup, args.clients, args.stalled)
            for b in (1, 6)
            for a in (1, 2, 4, 8, 16)
        ]
        results = [_run_config(config, args.repeat, log_dir, raw) for config in configs]
        print_scaling(results, args.repeat)
    else:
        config = RunConfig(args.agents, args.bodies, args.duration, args.warmup,
                           args.clients, args.stalled, args.calibrate,
                           args.calibrate_capture, args.client)  # fmt: skip
        print_main(_run_config(config, args.repeat, log_dir, raw), args.repeat)


def _run_config(config: RunConfig, repeat: int, log_dir: Path, raw: dict[str, Any]) -> RunResult:
    """``repeat`` runs of ``config`` (seeds 1..repeat); their medians."""
    runs = []
    for k in range(repeat):
        print(
            f"  run {k + 1}/{repeat}: {config.agents} agents × {config.bodies} bodies, "
            f"{config.duration_s:.0f} s …",
            file=sys.stderr,
            flush=True,
        )
        runs.append(asyncio.run(run_once(config, seed=k + 1, log_dir=log_dir)))
    raw.setdefault("runs", []).extend(asdict(r) for r in runs)
    return median_result(runs)
