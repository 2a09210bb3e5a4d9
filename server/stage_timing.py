"""How long each stage of the live path takes, as histograms at ``/metrics``.

The fused frame's own stamps (``t``, ``t_sent``) and the agents' capture times tell a client
how old a frame is; these histograms say where the server spent that time. The ingest and fusion
tasks (:mod:`skelfuse.server.ingest`) time their stages with ``time.perf_counter`` and record
them here (a bisect and three additions each, about a microsecond); the collector exposes them
as one histogram family, ``skelfuse_live_stage_seconds{stage=...}``:

- ``ingest``: one agent message decoded, validated and handled (``FusionHub.handle_message``);
- ``fusion``: one fusion step that produced a frame (``FusionHub.fuse_step``);
- ``publish``: that frame built and encoded once per feed variant and queued for every client
  (``Broadcaster.publish``);
- ``lag``: server time when the fusion step began minus the fused instant ``t``: the alignment
  wait plus the completing frame's transit, ingest and the fusion task's wake-up;
- ``send``: per client and frame, the start of ``publish`` (the message's ``t_sent``) to the
  frame's write into that client's socket (``Broadcaster.send_times``): the server's share of
  the age a client measures after ``t_sent``, without the client's own scheduling.

``bench/live/load.py`` reads them before and after its window (the difference of the cumulative
buckets is the window's histogram).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from prometheus_client.core import HistogramMetricFamily, Metric
from prometheus_client.registry import Collector

from skelfuse.server.histogram import Histogram

STAGE_BUCKETS_S: tuple[float, ...] = (
    25e-6, 50e-6, 100e-6, 200e-6, 300e-6, 500e-6, 750e-6,
    1e-3, 1.5e-3, 2e-3, 3e-3, 5e-3, 7.5e-3, 10e-3, 15e-3, 20e-3, 30e-3, 40e-3, 50e-3, 75e-3,
    0.1, 0.2, 0.5, 1.0,
)  # fmt: skip
"""Histogram upper bounds, seconds: tens of µs (a frame's ingest) to a second (a stall); close
enough together that a quantile interpolated within a bucket is within about 25 % of the truth."""

STAGES = ("ingest", "fusion", "publish", "lag", "send")


class StageTimes:
    """One :class:`Histogram` per stage of the live path (:data:`STAGES`)."""

    def __init__(self, buckets: Sequence[float] = STAGE_BUCKETS_S) -> None:
        self.ingest = Histogram(buckets)
        self.fusion = Histogram(buckets)
        self.publish = Histogram(buckets)
        self.lag = Histogram(buckets)
        self.send = Histogram(buckets)

    def by_stage(self) -> dict[str, Histogram]:
        """Every stage's histogram by its name in :data:`STAGES`."""
        return {"ingest": self.ingest, "fusion": self.fusion, "publish": self.publish,
                "lag": self.lag, "send": self.send}  # fmt: skip


class StageTimesCollector(Collector):
    """``/metrics`` view of a :class:`StageTimes`, read at scrape time."""

    def __init__(self, stages: StageTimes) -> None:
        self.stages = stages

    def collect(self) -> Iterator[Metric]:
        family = HistogramMetricFamily(
            "skelfuse_live_stage_seconds",
            "Time per stage of the live path: ingest (per agent message), fusion, publish "
            "(per fused frame), lag (fusion start minus the fused instant), send (publish to the "
            "write into each client's socket)",
            labels=["stage"],
        )
        for name, histogram in self.stages.by_stage().items():
            family.add_metric([name], histogram.cumulative(), histogram.sum_s)
        yield family
