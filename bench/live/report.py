"""The load benchmark's tables (Markdown, as in docs/benchmarks.md) and the median of repeats."""

from __future__ import annotations

import math
import statistics
from dataclasses import asdict, replace

from bench.live.agents import FPS
from bench.live.fusion_timing import FusionTiming
from bench.live.host_speed import HostSpeed
from bench.live.run import RunResult

# Targets of the load issue (docs/benchmarks.md, /work/shared/reliability.md L1/L2).
TARGET_P50_MS = 10.0
TARGET_P99_MS = 30.0
TARGET_FUSE_MS = 1.0


def median_result(runs: list[RunResult]) -> RunResult:
    """Field-wise median of several runs (counts: the worst run, so a loss is never hidden)."""
    out = RunResult(runs[0].config)
    worst = {"lost_frames", "sequence_gaps", "frames_rejected", "client_gaps_total",
             "client_gaps_max", "agent_drops_registered", "calibration_over_20ms",
             "calibration_server_silent", "baseline_over_20ms"}  # fmt: skip
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
    out.alignment = ", ".join(dict.fromkeys(r.alignment for r in runs))
    out.calibration_state = ", ".join(r.calibration_state for r in runs if r.calibration_state)
    out.calibration_icp = min(r.calibration_icp for r in runs)
    out.rejected_reasons = {}
    for r in runs:
        for reason, n in r.rejected_reasons.items():
            out.rejected_reasons[reason] = max(n, out.rejected_reasons.get(reason, 0))
    return out


WAIT_FIELDS = ("wait_p50_ms", "wait_p99_ms", "beyond_p50_ms", "beyond_p99_ms",
               "server_beyond_p50_ms", "server_beyond_p99_ms")  # fmt: skip
"""The figures taken from the wait reconstructed from the agents' captures (bench/live/waits.py)."""


def without_waits(r: RunResult) -> RunResult:
    """``r`` with :data:`WAIT_FIELDS` blanked (NaN, printed as a dash) when the server ran
    ``deadline``: it fuses without the frames that wait is taken from, and the wait is the
    server's ``lag`` instead (the reconstruction gave negative "beyond the wait" figures)."""
    if "deadline" not in r.alignment:
        return r
    blanked = replace(r)
    for name in WAIT_FIELDS:
        setattr(blanked, name, math.nan)
    return blanked


def ms(value: float, decimals: int = 1) -> str:
    """A figure in ms to one decimal (or ``decimals``), a dash when there was nothing to measure."""
    return "–" if math.isnan(value) else f"{value:.{decimals}f}"


def print_main(r: RunResult, repeat: int) -> None:
    """The main run's table: every metric, its target and the measured figure."""
    c = r.config
    expected_ingest = c.agents * FPS
    evicted = "not evicted" if r.stalled_evicted_after_s is None else (
        f"evicted after {r.stalled_evicted_after_s:.1f} s"
    )  # fmt: skip
    deadline = "deadline" in r.alignment
    r = without_waits(r)

    def waited(figure: str) -> str:
        """A figure from the reconstructed wait (:func:`without_waits`)."""
        return "n/a under `deadline` (server `lag` below)" if deadline else figure

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
         waited(f"{ms(r.wait_p50_ms)} / {ms(r.wait_p99_ms)}")),
        ("latency beyond the alignment wait p50 / p99 (ms)",
         f"≤ {TARGET_P50_MS:.0f} / ≤ {TARGET_P99_MS:.0f}",
         waited(f"{ms(r.beyond_p50_ms)} / {ms(r.beyond_p99_ms)}")),
        ("server share `t_sent − t` p50 / p99 (ms)", "—",
         f"{ms(r.server_p50_ms)} / {ms(r.server_p99_ms)}"),
        ("server share beyond the wait p50 / p99 (ms)", "—",
         waited(f"{ms(r.server_beyond_p50_ms)} / {ms(r.server_beyond_p99_ms)}")),
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
        f"clients ({c.client}) + {c.stalled} stalled, {r.window_s:.0f} s window after "
        f"{c.warmup_s:.0f} s warm-up{runs}\n"
    )
    print("| metric | target | measured |")
    print("|---|---|---|")
    for name, target, value in rows:
        print(f"| {name} | {target} | {value} |")
    print_stages_live(r)
    if c.calibrate is not None:
        print_calibration(r)
    if r.agents_late:
        print(f"\nThe agents process fell behind its schedule {r.agents_late} times.")
    for note in dict.fromkeys(r.notes):
        print(f"\nNote: {note}")


def print_stages_live(r: RunResult) -> None:
    """Where a fused frame's time goes, stage by stage, with where each figure comes from.

    Each row is its own distribution, so the p99s do not add up; the p50s nearly do.
    """
    r = without_waits(r)
    transit = r.lag_p50_ms - r.wait_p50_ms
    rows = [
        ("alignment wait: capture of the frame that completed the instant − `t`",
         "agents' capture times", r.wait_p50_ms, r.wait_p99_ms),
        ("ingest: decode + handle one agent message", "server `ingest`",
         r.ingest_p50_ms, r.ingest_p99_ms),
        ("fusion start − `t` (wait + transit + ingest + wake-up)", "server `lag`",
         r.lag_p50_ms, r.lag_p99_ms),
        ("→ transit + ingest + wake-up (p50 of lag − p50 of wait)", "derived",
         transit, math.nan),
        ("fusion step", "server `fusion`", r.fusion_p50_ms, r.fusion_p99_ms),
        ("publish: build + encode once per variant, queue for every client",
         "server `publish`", r.publish_p50_ms, r.publish_p99_ms),
        ("`t_sent` → client receive (publish, queue, send, client decode)", "clients",
         r.send_p50_ms, r.send_p99_ms),
        ("capture → client, beyond the alignment wait", "clients + agents",
         r.beyond_p50_ms, r.beyond_p99_ms),
    ]  # fmt: skip
    print(
        "\nPer stage (ms; server rows from `skelfuse_live_stage_seconds` over the window, "
        "interpolated in its buckets)\n"
    )
    print("| stage | measured by | p50 | p99 |")
    print("|---|---|---|---|")
    for name, source, p50, p99 in rows:
        print(f"| {name} | {source} | {ms(p50, 2)} | {ms(p99, 2)} |")


def print_calibration(r: RunResult) -> None:
    """The event loop while a calibration ran under this load, against the window before it."""
    c = r.config
    print(
        f"\nCalibration `{c.calibrate}` ({c.calibrate_capture_s:.0f} s capture) in the window: "
        f"{r.calibration_state}, {r.calibration_s:.1f} s\n"
    )
    print(f"| event loop | target | during the calibration ({r.calibration_s:.0f} s) | "
          f"before it, the load alone ({r.baseline_s:.0f} s) |")  # fmt: skip
    print("|---|---|---|---|")
    print(f"| longest stall (ms) | ≤ 20 | {ms(r.calibration_lag_max_ms)} | "
          f"{ms(r.baseline_lag_max_ms)} |")  # fmt: skip
    print(f"| p99 stall (ms, bucket bound) | — | {ms(r.calibration_lag_p99_ms)} | "
          f"{ms(r.baseline_lag_p99_ms)} |")  # fmt: skip
    print(f"| ticks late by over 20 ms | 0 | {r.calibration_over_20ms} | "
          f"{r.baseline_over_20ms} |")  # fmt: skip
    print(f"| … per second | 0 | {r.calibration_over_20ms / max(r.calibration_s, 1e-9):.2f} | "
          f"{r.baseline_over_20ms / max(r.baseline_s, 1e-9):.2f} |")  # fmt: skip
    print(f'| agents\' "server silent" lines | 0 | {r.calibration_server_silent} | — |')


def print_scaling(results: list[RunResult], repeat: int) -> None:
    """One row per (agents, bodies) configuration."""
    runs = f" (median of {repeat} runs each)" if repeat > 1 else ""
    print(f"\nScaling{runs}: latency in ms; 'beyond' = beyond the alignment wait\n")
    print(
        "| agents | bodies | ingest/s (expected) | lost | seq gaps | fused/s | client gaps | "
        "instants skipped | "
        "raw p50 / p99 | wait p50 | beyond p50 / p99 | server beyond p50 / p99 | "
        "ingest / fusion / publish / send p50 | "
        "server CPU % | RSS MB | stalled evicted (s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in map(without_waits, results):
        c = r.config
        ev = "–" if r.stalled_evicted_after_s is None else f"{r.stalled_evicted_after_s:.1f}"
        print(
            f"| {c.agents} | {c.bodies} | {r.ingest_fps:.0f} ({c.agents * FPS:.0f}) | "
            f"{r.lost_frames} | {r.sequence_gaps} | {r.fused_fps:.1f} | {r.client_gaps_total} | "
            f"{r.skipped_instants} | "
            f"{ms(r.latency_p50_ms)} / {ms(r.latency_p99_ms)} | {ms(r.wait_p50_ms)} | "
            f"{ms(r.beyond_p50_ms)} / {ms(r.beyond_p99_ms)} | "
            f"{ms(r.server_beyond_p50_ms)} / {ms(r.server_beyond_p99_ms)} | "
            f"{ms(r.ingest_p50_ms, 2)} / {ms(r.fusion_p50_ms)} / {ms(r.publish_p50_ms, 2)} / "
            f"{ms(r.send_p50_ms)} | "
            f"{r.server_cpu_pct:.0f} | {r.server_rss_end_mb:.0f} | {ev} |"
        )
    for note in dict.fromkeys(n for r in results for n in r.notes):
        print(f"\nNote: {note}")


def print_fusion(timings: list[FusionTiming], speeds: list[HostSpeed] | None = None) -> None:
    """The in-process fusion cost, one row per sensors × bodies; ``speeds``: the host's
    reference workloads timed before and after (bench/live/host_speed.py)."""
    drive = timings[0].drive if timings else "arrivals"
    print(
        "\nIn-process fusion cost (production classes, simulated time), median over steps; "
        f"fuse_step called at each {'arrival and deadline' if drive == 'arrivals' else 'period'}\n"
    )
    print(
        "| sensors × bodies | `fuse_step` wall median (p99) ms | `fuse_step` CPU median ms "
        "| target | late sensors per frame | `FusionPipeline.update` wall ms "
        "| JSON encode per frame ms | `handle_message` per frame ms |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for f in timings:
        target = f"≤ {TARGET_FUSE_MS:.0f}" if (f.sensors, f.bodies) == (4, 6) else "—"
        print(
            f"| {f.sensors} × {f.bodies} | {f.fuse_step_ms:.2f} ({f.fuse_step_p99_ms:.2f}) | "
            f"{f.fuse_step_cpu_ms:.2f} | {target} | {f.late_per_frame:.2f} | {f.tracker_ms:.2f} | "
            f"{f.encode_json_ms:.3f} | {f.handle_message_ms:.3f} |"
        )
    if speeds:
        cells = ", ".join(f"{s.python_us:.0f} / {s.memory_us:.0f}" for s in speeds)
        print(
            f"\nHost speed before, after (bench/live/host_speed.py: small Python work / a 16 MB "
            f"sum, µs; the host of 2026-11-22 to 24 when quiet ~212 / 460–690, the faster host of "
            f"2026-11-24 20:00 ~100 / 540–630): {cells}"
        )
    print_stages(timings)


def print_stages(timings: list[FusionTiming]) -> None:
    """Where `fuse_step`'s time goes: median ms per pipeline stage (bench/live/fusion_stages.py)."""
    stages = list(timings[0].stages_ms) if timings else []
    if not stages:
        return
    print("\nFusion step per stage (bench/live/fusion_stages.py), wall median ms over steps\n")
    print("| sensors × bodies | " + " | ".join(stages) + " | `fuse_step` |")
    print("|---|" + "---|" * (len(stages) + 1))
    for f in timings:
        cells = " | ".join(f"{f.stages_ms.get(stage, float('nan')):.3f}" for stage in stages)
        print(f"| {f.sensors} × {f.bodies} | {cells} | {f.fuse_step_ms:.3f} |")
