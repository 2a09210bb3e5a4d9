"""The live path's stage histograms (server/stage_timing.py) as /metrics shows them, and the load
bench's quantile over a window of two scrapes (bench/live/stages.py)."""

from __future__ import annotations

import math

import pytest
from prometheus_client import CollectorRegistry, generate_latest

from bench.live.stages import parse_stages, window_quantile
from skelfuse.server.stage_timing import STAGES, StageTimes, StageTimesCollector


def scrape(stages: StageTimes) -> str:
    registry = CollectorRegistry()
    registry.register(StageTimesCollector(stages))
    return generate_latest(registry).decode()


def test_each_stage_is_a_labelled_histogram_at_metrics() -> None:
    stages = StageTimes()
    for value in (0.00004, 0.00004, 0.0002, 0.003):
        stages.ingest.record(value)
    stages.fusion.record(0.006)
    stages.lag.record(-0.001)  # a clock step: counted as 0, not lost
    text = scrape(stages)
    assert 'skelfuse_live_stage_seconds_bucket{le="5e-05",stage="ingest"} 2.0' in text
    assert 'skelfuse_live_stage_seconds_count{stage="ingest"} 4.0' in text
    assert 'skelfuse_live_stage_seconds_count{stage="fusion"} 1.0' in text
    assert 'skelfuse_live_stage_seconds_bucket{le="2.5e-05",stage="lag"} 1.0' in text
    assert 'skelfuse_live_stage_seconds_count{stage="publish"} 0.0' in text
    parsed = parse_stages(text)
    assert set(parsed) == set(STAGES)
    assert parsed["ingest"][-1] == (math.inf, 4.0)
    assert stages.ingest.max_s == pytest.approx(0.003)


def test_a_window_quantile_counts_only_what_happened_between_the_scrapes() -> None:
    stages = StageTimes()
    for _ in range(1000):
        stages.fusion.record(0.040)  # before the window: slow steps
    before = parse_stages(scrape(stages))
    for k in range(100):
        stages.fusion.record(0.0011 + k * 0.0008 / 99)  # 1.1–1.9 ms: all in (1, 2] ms buckets
    after = parse_stages(scrape(stages))
    p50 = window_quantile(before["fusion"], after["fusion"], 0.5)
    p99 = window_quantile(before["fusion"], after["fusion"], 0.99)
    assert 1.0 <= p50 <= 2.0 and 1.0 <= p99 <= 2.0 and p50 < p99
    assert window_quantile(None, after["fusion"], 0.5) > 30  # the whole history: mostly 40 ms
    assert math.isnan(window_quantile(after["fusion"], after["fusion"], 0.5))  # nothing new
    assert math.isnan(window_quantile(None, None, 0.5))  # a server without the histogram


def test_a_quantile_past_every_bound_is_the_highest_bound() -> None:
    stages = StageTimes(buckets=(0.001, 0.01))
    stages.publish.record(5.0)
    after = parse_stages(scrape(stages))["publish"]
    assert window_quantile(None, after, 0.99) == pytest.approx(10.0)
