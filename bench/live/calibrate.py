"""The load benchmark's calibration under load (``python -m bench load --calibrate auto``).

Part-way into the measured window a full calibration run is started through REST, exactly as
``python -m bench calibration_stall`` does it (its
:func:`~bench.live.calibration_stall.calibrate_once`, reused): the event loop's lag while the run
lasts (``server/loop_lag.py`` at ``/metrics``: the longest stall, the 99th percentile, ticks over
20 ms and over 100 ms) and the "server silent" lines the fake agents logged meanwhile (each is an
agent that stopped hearing the server and registered again, dropping frames). The same loop-lag
figures over the part of the window before the run are the baseline: what this machine's load
alone costs the loop.

The fake agents answer the server's ``depth_cloud`` requests with the room as a simulated
Kinect v2 sees it from their pose (rendered once at start-up, so the agents process keeps its
pace), so ``auto`` runs every stage: skeleton capture and solve, depth clouds, ICP, floor.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass
from pathlib import Path

from bench.live.calibration_stall import LagSnapshot, StallResult, calibrate_once, scrape, window


@dataclass(frozen=True)
class LagWindow:
    """Loop-lag figures between two scrapes: how far apart (s), ticks, longest and p99 stall (ms;
    the p99 is its bucket's upper bound), ticks over 20 ms and over 100 ms."""

    seconds: float
    ticks: int
    max_ms: float
    p99_ms: float
    over_20ms: int
    over_100ms: int


def lag_window(before: LagSnapshot, after: LagSnapshot, seconds: float) -> LagWindow:
    """:func:`bench.live.calibration_stall.window` in ms, for scrapes ``seconds`` apart."""
    ticks, max_s, p99_s, over_20, over_100 = window(before, after)
    return LagWindow(seconds, ticks, max_s * 1e3, p99_s * 1e3, over_20, over_100)


async def calibrate_under_load(
    base_url: str, method: str, capture_s: float, start_after_s: float, agent_logs: list[Path]
) -> tuple[LagWindow, StallResult]:
    """Wait ``start_after_s``, then run one ``method`` calibration and wait for its end.

    Returns the loop lag from the call until the run started (the baseline under the same load)
    and the run's own figures.
    """
    before = await asyncio.to_thread(scrape, base_url)
    started = time.monotonic()
    await asyncio.sleep(start_after_s)
    after = await asyncio.to_thread(scrape, base_url)
    baseline = lag_window(before, after, time.monotonic() - started)
    run = await asyncio.to_thread(calibrate_once, base_url, capture_s, agent_logs, method)
    return baseline, run
