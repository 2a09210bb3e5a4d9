"""The bench's host speed probes (bench/live/host_speed.py) and where the load report shows them."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest

from bench.live import encode as load_encode, host_speed as module
from bench.live.host_speed import HostSpeed, host_speed


def test_the_median_of_the_timed_runs_is_reported(monkeypatch: pytest.MonkeyPatch) -> None:
    # An injected clock: the timed runs take 5, 1, 3 ms (start and end readings in turn); the
    # warm-up runs before them read no clock.
    readings: Iterator[float] = iter([0.0, 0.005, 1.0, 1.001, 2.0, 2.003])
    monkeypatch.setattr(load_encode.time, "perf_counter", lambda: next(readings))
    calls: list[int] = []
    assert load_encode.median_us(lambda: calls.append(1), runs=3) == pytest.approx(3000.0)
    assert len(calls) == 6  # three to warm up, untimed, then the three


def test_host_speed_times_its_workloads_with_the_shared_timer(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    timed: list[int] = []
    monkeypatch.setattr(module, "median_us", lambda work, runs: timed.append(runs) or 7.0)
    assert host_speed(repeats=4) == HostSpeed(7.0, 7.0)
    assert timed == [4, 4]


def test_both_workloads_are_timed() -> None:
    speed = host_speed(repeats=3)
    for value in (speed.python_us, speed.memory_us):
        assert math.isfinite(value) and value > 0.0


def test_the_fusion_table_shows_the_host_speed_before_and_after(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from bench.live.fusion_timing import fusion_timing
    from bench.live.report import print_fusion

    timing = fusion_timing(sensors=2, bodies=2, steps=3, warmup=10)
    print_fusion([timing], [HostSpeed(211.6, 640.2), HostSpeed(480.0, 901.0)])
    out = capsys.readouterr().out
    assert "212 / 640, 480 / 901" in out
    print_fusion([timing])
    assert "Host speed" not in capsys.readouterr().out
