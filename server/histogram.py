"""A histogram of durations kept in plain counters, for the server's own ``/metrics`` collectors.

The live-stage timings (:mod:`skelfuse.server.stage_timing`) and the event-loop lag
(:mod:`skelfuse.server.loop_lag`) record into it on the event loop (a bisect and three
additions, about a microsecond) and expose it as Prometheus buckets.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence


class Histogram:
    """Counts of values by upper bound (seconds), their sum and their maximum.

    ``bucket_counts[i]`` counts the values at most ``buckets[i]`` and more than the bound before
    it; the last slot counts values above every bound.
    """

    def __init__(self, buckets: Sequence[float]) -> None:
        self.buckets = tuple(buckets)
        self.bucket_counts = [0] * (len(self.buckets) + 1)
        self.count = 0
        self.sum_s = 0.0
        self.max_s = 0.0

    def record(self, value_s: float) -> None:
        """Count one value (seconds; a negative one, from a clock step, counts as 0)."""
        value_s = max(0.0, value_s)
        self.count += 1
        self.sum_s += value_s
        self.max_s = max(self.max_s, value_s)
        self.bucket_counts[bisect.bisect_left(self.buckets, value_s)] += 1

    def cumulative(self) -> list[tuple[str, int]]:
        """Prometheus buckets: (upper bound, values at most that), ending with ``+Inf``."""
        out: list[tuple[str, int]] = []
        total = 0
        for bound, count in zip((*self.buckets, float("inf")), self.bucket_counts, strict=True):
            total += count
            out.append(("+Inf" if bound == float("inf") else repr(bound), total))
        return out
