"""The bench's per-stage breakdown of a fusion step (bench/fusion_stages.py)."""

from __future__ import annotations

import math

from bench.fusion_stages import STAGES
from bench.fusion_timing import fusion_timing
from skelfuse.fusion import hub, pipeline as module


def test_every_stage_is_timed_and_the_library_is_restored() -> None:
    originals = {name: getattr(module, name) for name in ("views_at", "filter_all")}
    late = hub.views_with_late  # the deadline policy's views (a sensor late): views_at too
    timing = fusion_timing(sensors=2, bodies=2, steps=5, warmup=40)  # bones estimated by then
    assert list(timing.stages_ms) == list(STAGES)
    for stage in STAGES:
        if stage != "other":  # the rest can be a hair below 0 from clock resolution
            assert timing.stages_ms[stage] > 0.0, stage
        assert math.isfinite(timing.stages_ms[stage]), stage
    # The stages lie inside the step: their medians cannot exceed the step's by much.
    assert sum(v for k, v in timing.stages_ms.items() if k != "other") < 2 * timing.fuse_step_ms
    for name, function in originals.items():
        assert getattr(module, name) is function
    assert hub.views_with_late is late
