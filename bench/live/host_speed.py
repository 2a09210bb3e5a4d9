"""How fast the host runs right now: two fixed reference workloads, timed.

This machine is shared, and its speed changes for minutes at a time without the load average
inside it showing anything. Two kinds of slow minutes were seen on 2026-11-24 (docs/benchmarks.md,
"Load", 14:00–14:57), with the 4 × 6 fusion step (bench/live/fusion_timing.py) timed between probes:

- the memory is slower: summing 16 MB takes 850–950 µs instead of 460–690 (a neighbour sharing
  the caches or the memory bus), small Python work runs as fast as ever, and the fusion step,
  whose code and arrays the rest of each period evicts from the caches, takes 1.0–1.15 ms
  instead of 0.90–0.94;
- everything runs at about half speed (small Python work twice its quiet time): the step then
  takes ~2 ms.

The machine itself changes too: from 2026-11-24 20:00 the sessions ran on a host whose small
Python work takes half the time (~100 µs) and whose 16 MB sum takes about as long (540–630 µs);
the 4 × 6 step took 0.57–0.59 ms there.

A figure in microseconds then says as much about those minutes as about the code. A bench
reports :func:`host_speed` next to its figures so that a slow run can be told from slow code
(a slow spell inside a run, between two quiet probes, still goes unseen).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.live.encode import median_us

_ROUNDS = 200
_MEMORY_VALUES = 2_000_000  # 16 MB of float64: more than the caches hold


@dataclass(frozen=True)
class HostSpeed:
    """Median µs of the two reference workloads (:func:`host_speed`)."""

    python_us: float
    """Small numpy calls on one (25, 3) skeleton, dict and list work: ~212 µs on the host of
    2026-11-22 to 24 when quiet, ~100 µs on the host of 2026-11-24 20:00."""
    memory_us: float
    """One sum over 16 MB of float64: ~460–690 µs on the host of 2026-11-22 to 24 when quiet,
    540–630 µs on the host of 2026-11-24 20:00."""


def _python_work() -> None:
    """What the fusion step does most, on data that stays in the caches."""
    joints = np.arange(75.0).reshape(25, 3)
    kept: dict[int, np.ndarray] = {}
    rows: list[float] = []
    for k in range(_ROUNDS):
        moved = joints + float(k)
        kept[k % 7] = moved
        rows.append(float(moved[3, 1]))


def host_speed(repeats: int = 15) -> HostSpeed:
    """Time both workloads, ``repeats`` runs each after as many to warm up (medians)."""
    values = np.random.default_rng(0).random(_MEMORY_VALUES)
    return HostSpeed(median_us(_python_work, repeats), median_us(values.sum, repeats))
