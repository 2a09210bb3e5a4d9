"""The load benchmark's per-stage breakdown: the server's stage histograms over the window.

The server times its stages (``server/stage_timing.py``: ``skelfuse_live_stage_seconds`` with
``stage`` = ingest, fusion, publish, lag); :func:`scrape_stages` reads the cumulative buckets,
:func:`window_quantile` takes the window's histogram (end minus start) and interpolates a
quantile linearly inside its bucket, as Prometheus's ``histogram_quantile`` does. The bench adds
what only the clients and the agents know, per fused frame (``bench/live/run.py``): the exact
alignment wait, the server's share after it, and ``t_sent`` → client receive.
"""

from __future__ import annotations

import math
import urllib.request

from prometheus_client.parser import text_string_to_metric_families

STAGE_FAMILY = "skelfuse_live_stage_seconds"

Buckets = tuple[tuple[float, float], ...]
"""Cumulative counts by upper bound (seconds, ascending, ``inf`` last)."""


def parse_stages(text: str) -> dict[str, Buckets]:
    """Every stage's cumulative buckets in a ``/metrics`` text (empty when the server has none)."""
    by_stage: dict[str, list[tuple[float, float]]] = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            if sample.name == STAGE_FAMILY + "_bucket":
                stage = sample.labels["stage"]
                by_stage.setdefault(stage, []).append((float(sample.labels["le"]), sample.value))
    return {stage: tuple(sorted(rows)) for stage, rows in by_stage.items()}


def scrape_stages(base_url: str) -> dict[str, Buckets]:
    """:func:`parse_stages` of the server's ``/metrics``."""
    with urllib.request.urlopen(base_url + "/metrics/", timeout=10) as response:
        return parse_stages(response.read().decode())


def window_quantile(before: Buckets | None, after: Buckets | None, q: float) -> float:
    """The ``q`` quantile (0–1) of the values counted between two scrapes, in ms.

    Linear inside the bucket that holds it (from the bound below, 0 for the first); a quantile
    in the last, open bucket is reported as the highest finite bound. NaN when nothing was
    counted (or the server has no such stage).
    """
    if not after:
        return math.nan
    start = dict(before or ())
    counts = [(bound, n - start.get(bound, 0.0)) for bound, n in after]
    total = counts[-1][1]
    if total <= 0:
        return math.nan
    rank = q * total
    lower, below = 0.0, 0.0
    for bound, cumulative in counts:
        if cumulative >= rank:
            if math.isinf(bound):
                return lower * 1e3
            inside = cumulative - below
            fraction = 0.0 if inside <= 0 else (rank - below) / inside
            return (lower + (bound - lower) * fraction) * 1e3
        lower, below = bound, cumulative
    return lower * 1e3  # not reached: the +Inf bucket holds every value
