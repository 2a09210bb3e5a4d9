"""The event-loop lag monitor (server/loop_lag.py) on a fake clock whose sleeps overrun as told,
and what it shows at /metrics."""

from __future__ import annotations

import asyncio

import pytest
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families

from skelfuse.server.loop_lag import LoopLagCollector, LoopLagMonitor


class OverrunningClock:
    """Each sleep takes what was asked plus the next of ``overruns``; then the run stops."""

    def __init__(self, overruns: list[float]) -> None:
        self.now = 100.0
        self.overruns = overruns

    def time(self) -> float:
        return 1_700_000_000.0 + self.now

    def monotonic(self) -> float:
        return self.now

    async def sleep(self, seconds: float) -> None:
        if not self.overruns:
            raise asyncio.CancelledError
        self.now += seconds + self.overruns.pop(0)


async def test_each_wake_up_is_counted_by_how_late_it_came() -> None:
    clock = OverrunningClock([0.0005, 0.0, 0.015, 0.3, 2.5, -0.001])
    monitor = LoopLagMonitor(clock)
    with pytest.raises(asyncio.CancelledError):
        await monitor.run()
    assert monitor.count == 6
    assert monitor.max_s == pytest.approx(2.5)
    assert monitor.sum_s == pytest.approx(2.8155)
    cumulative = dict(monitor.cumulative())
    assert cumulative["0.001"] == 3  # 0.5 ms, on time, and early (counted as 0)
    assert cumulative["0.01"] == 3 and cumulative["0.02"] == 4
    assert cumulative["0.2"] == 4 and cumulative["0.5"] == 5
    assert cumulative["2.0"] == 5 and cumulative["5.0"] == 6 and cumulative["+Inf"] == 6


def test_metrics_show_the_histogram_and_the_longest_stall() -> None:
    monitor = LoopLagMonitor(OverrunningClock([]))
    for lag in (0.0002, 0.004, 0.03):
        monitor.record(lag)
    registry = CollectorRegistry()
    registry.register(LoopLagCollector(monitor))
    samples = {
        (s.name, s.labels.get("le")): s.value
        for family in text_string_to_metric_families(generate_latest(registry).decode())
        for s in family.samples
    }
    assert samples[("skelfuse_event_loop_lag_seconds_bucket", "0.02")] == 2
    assert samples[("skelfuse_event_loop_lag_seconds_bucket", "0.05")] == 3
    assert samples[("skelfuse_event_loop_lag_seconds_count", None)] == 3
    assert samples[("skelfuse_event_loop_lag_seconds_sum", None)] == pytest.approx(0.0342)
    assert samples[("skelfuse_event_loop_lag_max_seconds", None)] == pytest.approx(0.03)
