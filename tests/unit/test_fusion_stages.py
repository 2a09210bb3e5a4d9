"""The bench's per-stage breakdown of a fusion step (bench/live/fusion_stages.py), through the
pipeline's public stage timer."""

from __future__ import annotations

import math

from bench.live.fusion_stages import STAGES, StageClock, stage_timers
from bench.live.fusion_timing import fusion_timing
from skelfuse.fusion import pipeline as module
from skelfuse.fusion.pipeline import NO_TIMER, FusionPipeline
from skelfuse.fusion.settings import FusionSettings


def test_every_stage_is_timed() -> None:
    timing = fusion_timing(sensors=2, bodies=2, steps=5, warmup=40)  # bones estimated by then
    assert list(timing.stages_ms) == list(STAGES)
    for stage in STAGES:
        if stage != "other":  # the rest can be a hair below 0 from clock resolution
            assert timing.stages_ms[stage] > 0.0, stage
        assert math.isfinite(timing.stages_ms[stage]), stage
    # The stages lie inside the step: their medians cannot exceed the step's by much.
    assert sum(v for k, v in timing.stages_ms.items() if k != "other") < 2 * timing.fuse_step_ms


def test_the_pipeline_names_every_stage_it_times() -> None:
    """Each stage the pipeline tells its timer of is one of its documented STAGES, and the
    bench's table has every one of them but ``update`` (kept apart)."""
    heard: list[str] = []

    class Recorder(StageClock):
        def stage(self, name: str):  # type: ignore[no-untyped-def]
            heard.append(name)
            return super().stage(name)

    pipeline = FusionPipeline(FusionSettings(), Recorder())
    pipeline.update([], 0.0)
    assert heard == ["update", "associate"]  # no persons: nothing past association
    assert set(module.STAGES) - {"update"} == set(STAGES) - {"other"}


def test_stage_timers_time_only_inside_the_block_and_keep_one_clock() -> None:
    pipeline = FusionPipeline(FusionSettings())
    clock = StageClock()
    for _ in range(2):  # the bench's periods by stage: the same clock each time
        with stage_timers(pipeline, clock) as inside:
            assert inside is clock and pipeline.timer is clock
            pipeline.update([], 0.0)
            clock.finish(1.0)
        assert pipeline.timer is NO_TIMER  # between them the library runs untimed
    assert len(clock.steps) == 2 and len(clock.updates) == 2
    assert all(0.0 < seconds < 1.0 for seconds in clock.updates)
    assert all(0.0 < step["associate"] < 1.0 for step in clock.steps)


def test_the_step_figures_and_the_stage_figures_come_from_different_periods() -> None:
    timing = fusion_timing(sensors=2, bodies=2, steps=6, warmup=40)
    assert math.isfinite(timing.tracker_ms) and timing.tracker_ms > 0.0
    # The step as the library runs it holds the tracker's update and more.
    assert 0.0 < timing.tracker_ms < 2 * timing.fuse_step_ms
