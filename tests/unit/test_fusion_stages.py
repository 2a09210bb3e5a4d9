"""The bench's per-stage breakdown of a fusion step (bench/fusion_stages.py)."""

from __future__ import annotations

import math

from bench.fusion_stages import STAGES
from bench.fusion_timing import fusion_timing
from skelfuse.fusion import engine, pipeline as module


def test_every_stage_is_timed_and_the_library_is_restored() -> None:
    originals = {name: getattr(module, name) for name in ("views_at", "filter_all")}
    late = engine.views_with_late  # the deadline policy's views (a sensor late): views_at too
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
    assert engine.views_with_late is late


def test_stage_timers_wrap_only_inside_the_block_and_keep_one_clock() -> None:
    from bench.fusion_stages import StageClock, stage_timers
    from skelfuse.fusion.pipeline import FusionPipeline
    from skelfuse.fusion.settings import FusionSettings

    pipeline = FusionPipeline(FusionSettings())
    filter_all = module.filter_all
    clock = StageClock()
    for _ in range(2):  # the bench's periods by stage: the same clock each time
        with stage_timers(pipeline, clock) as inside:
            assert inside is clock
            assert "update" in pipeline.__dict__ and module.filter_all is not filter_all
            pipeline.update([], 0.0)
            clock.finish(1.0)
        # Between them the library runs untouched.
        assert "update" not in pipeline.__dict__ and "associate" not in pipeline.tracker.__dict__
        assert module.filter_all is filter_all
    assert len(clock.steps) == 2 and len(clock.updates) == 2
    assert all(0.0 < seconds < 1.0 for seconds in clock.updates)


def test_the_step_figures_and_the_stage_figures_come_from_different_periods() -> None:
    timing = fusion_timing(sensors=2, bodies=2, steps=6, warmup=40)
    assert math.isfinite(timing.tracker_ms) and timing.tracker_ms > 0.0
    # The step as the library runs it holds the tracker's update and more.
    assert 0.0 < timing.tracker_ms < 2 * timing.fuse_step_ms
