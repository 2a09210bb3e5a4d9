"""bench/live/load.py's alignment-wait reconstruction against a simulated server (issue 11 item 6).

The server's rule, simulated here: instant ``t`` is fused once every sensor has a frame whose
capture, mapped with the offset estimate the server held when the frame arrived, is at or past
``t``; its ``lag`` is then the arrival of the last such frame minus ``t``. On a ``phased`` grid,
a millisecond before one sensor's frames, with offset estimates that move during the run, the
reconstruction must give each instant's wait, and so never read above the lag.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from bench.live.waits import OffsetSeries, alignment_waits, offset_series

Arr = npt.NDArray[np.floating[Any]]
PERIOD = 1 / 30
DELIVERY_S = 0.0008
START = 1_800_000_000.0
FRAMES = 300  # 10 s
PHASES = {"a": 0.010, "b": 0.020, "c": 0.030}  # capture phases on the (shared) true clock


def estimate(sensor: str, t: Arr) -> Arr:
    """The server's offset estimate (s) at time ``t``: ``a``'s moves from +0.5 ms to -4.5 ms.
    (Never above the delivery time: a frame is not mapped after it arrived.)"""
    if sensor == "a":
        return 0.0005 - 0.005 * (t - START) / (FRAMES * PERIOD)
    return np.full(t.shape, {"b": 0.0005, "c": -0.004}[sensor])


def simulate() -> tuple[
    Arr, dict[str, Arr], Arr,
    Arr,
]:  # fmt: skip
    """Fused instants, the agents' capture stamps, the true wait and the server's lag."""
    captures = {s: START + phase + PERIOD * np.arange(FRAMES) for s, phase in PHASES.items()}
    # Phased: the grid 1 ms before a's frames as the server maps them at first; as its estimate
    # moves, a's frames come before the instants and the server waits for the next ones.
    fused_t = START + PHASES["a"] - 0.0005 + PERIOD * np.arange(2, FRAMES - 2)
    last_mapped = np.full(fused_t.shape, -np.inf)
    last_arrival = np.full(fused_t.shape, -np.inf)
    for sensor, caps in captures.items():
        arrival = caps + DELIVERY_S
        mapped = caps + estimate(sensor, arrival)
        idx = np.searchsorted(mapped, fused_t, side="left")
        last_mapped = np.maximum(last_mapped, mapped[idx])
        last_arrival = np.maximum(last_arrival, arrival[idx])
    return fused_t, captures, last_mapped - fused_t, last_arrival - fused_t


def sampled_offsets(every_s: float) -> dict[str, OffsetSeries]:
    """What the bench reads from /api/sensors every ``every_s`` during the run."""
    times = START + np.arange(0.0, FRAMES * PERIOD + every_s, every_s)
    samples = [(float(t), {s: float(estimate(s, np.array([t]))[0]) for s in PHASES}) for t in times]
    return offset_series(samples)


def test_the_waits_are_the_servers_and_never_above_its_lag() -> None:
    fused_t, captures, true_wait, lag = simulate()
    waits = alignment_waits(fused_t, captures, sampled_offsets(1.0))
    np.testing.assert_allclose(waits, true_wait, atol=2e-4)
    assert np.all(waits <= lag + 1e-9)
    assert np.any(waits < 0.020) and np.any(waits > 0.025)  # c last, then a's next frame


def test_the_offset_at_the_end_of_the_run_alone_reads_whole_periods_too_long() -> None:
    # What the bench did before: one offset per sensor, read at the end (a's is then -4.5 ms,
    # so its early frames, mapped 1 ms after the instants by the server, seem to miss them).
    fused_t, captures, _, lag = simulate()
    end = {
        s: OffsetSeries.constant(float(estimate(s, np.array([START + 10.0]))[0])) for s in PHASES
    }
    waits = alignment_waits(fused_t, captures, end)
    assert np.mean(waits > lag + 0.005) > 0.1


def test_offset_series_holds_and_skips_missing_estimates() -> None:
    series = offset_series([(2.0, {"a": 0.002, "b": None}), (1.0, {"a": 0.0, "b": None})])
    assert set(series) == {"a"}
    np.testing.assert_allclose(series["a"].at(np.array([0.0, 1.5, 9.0])), [0.0, 0.001, 0.002])
