"""How long the event loop stalls: a coroutine that sleeps a few ms in a loop, and how late it woke.

Anything that holds the loop (a long callback, or another thread of this process that keeps the
GIL, as open3d's ICP did) shows as lateness here, and every client, agent and fusion step waits
as long. :class:`LoopLagMonitor` runs as one of the server's tasks; :class:`LoopLagCollector`
exposes what it saw at ``/metrics`` (``skelfuse_event_loop_lag_seconds``, a histogram of the
lateness of each 5 ms tick, and ``skelfuse_event_loop_lag_max_seconds``, the largest since the
server started), which ``bench/live/calibration_stall.py`` reads around a calibration.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from prometheus_client.core import GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector

from skelfuse.server.clock import Clock
from skelfuse.server.histogram import Histogram

TICK_S = 0.005
"""How long the monitor sleeps each time: a stall shorter than this can hide between ticks."""
LAG_BUCKETS_S: tuple[float, ...] = (
    0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0,
)  # fmt: skip
"""Histogram upper bounds, seconds; 0.02 is the issue's target, 1 s an agent's heartbeat."""


class LoopLagMonitor(Histogram):
    """Sleeps ``tick_s`` on ``clock`` over and over and records how late each wake-up was.

    ``count``, ``sum_s`` and ``max_s`` cover every tick since :meth:`run` started;
    ``bucket_counts[i]`` counts the ticks whose lateness was at most ``buckets[i]`` and more
    than the bound before it (the last slot: more than every bound).
    """

    def __init__(
        self, clock: Clock, tick_s: float = TICK_S, buckets: Sequence[float] = LAG_BUCKETS_S
    ) -> None:
        super().__init__(buckets)
        self._clock = clock
        self.tick_s = tick_s

    async def run(self) -> None:
        """Tick until cancelled."""
        while True:
            before = self._clock.monotonic()
            await self._clock.sleep(self.tick_s)
            self.record(self._clock.monotonic() - before - self.tick_s)


class LoopLagCollector(Collector):
    """``/metrics`` view of a :class:`LoopLagMonitor`, read at scrape time."""

    def __init__(self, monitor: LoopLagMonitor) -> None:
        self.monitor = monitor

    def collect(self) -> Iterator[Metric]:
        monitor = self.monitor
        histogram = HistogramMetricFamily(
            "skelfuse_event_loop_lag_seconds",
            f"How late the event loop woke from a {monitor.tick_s * 1000:.0f} ms sleep",
        )
        histogram.add_metric([], monitor.cumulative(), monitor.sum_s)
        yield histogram
        yield GaugeMetricFamily(
            "skelfuse_event_loop_lag_max_seconds",
            "The longest event loop stall since the server started",
            value=monitor.max_s,
        )
