"""Where one fused frame's time goes: wall time per pipeline stage, measured in the bench only.

The library reads no clock: its pipeline tells a :class:`~skelfuse.fusion.pipeline.StageTimer`
when each stage starts and ends (``FusionPipeline.timer``, nothing by default). A
:class:`StageClock` is such a timer; :func:`stage_timers` sets it on a pipeline for the duration
of a ``with`` block. Stages (docs/fusion.md numbering):

- ``views``: steps 1–2, each sensor's bodies at the instant, in the world frame (with a sensor
  late at the deadline, the engine's late path, which carries it forward);
- ``associate``: step 3, ``PersonTracker.associate``;
- ``labels``: step 4, the mirror labels;
- ``weights``: steps 5–6, the confidence terms, the fusions, joint confidence and carriers;
- ``bones observe``: the online bone observation;
- ``walking check``: the walking check, all persons;
- ``filter``: step 7;
- ``bone fit``: step 8;
- ``other``: the rest of ``fuse_step`` (grid bookkeeping, batch build, track moves, building
  the output persons, confirming tracks).

``update`` (steps 3–8 as a whole) is kept apart (:attr:`StageClock.updates`). A timed step reads
the clock twice per stage; ``bench/live/fusion_timing.py`` still times one step in three by stage
and takes the step's own figures from the other two, which run with no timer at all.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from skelfuse.fusion.pipeline import NO_TIMER, FusionPipeline

STAGES = (
    "views",
    "associate",
    "labels",
    "weights",
    "bones observe",
    "walking check",
    "filter",
    "bone fit",
    "other",
)


class StageClock:
    """A :class:`~skelfuse.fusion.pipeline.StageTimer` keeping seconds per stage of the current
    step, and every finished step's figures."""

    def __init__(self) -> None:
        self.current: dict[str, float] = {}
        self.steps: list[dict[str, float]] = []
        self.updates: list[float] = []
        """Seconds in ``FusionPipeline.update`` (steps 3–8) per finished step that ran it."""
        self._update_s: float | None = None

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the stage ``name`` into the current step (``update`` apart from the others)."""
        start = time.perf_counter()
        try:
            yield
        finally:
            seconds = time.perf_counter() - start
            if name == "update":
                self._update_s = seconds
            else:
                self.current[name] = self.current.get(name, 0.0) + seconds

    def finish(self, total_s: float) -> None:
        """Close the current step, which took ``total_s`` in all (``other``: what is left)."""
        step = dict(self.current)
        step["other"] = total_s - sum(step.values())
        self.steps.append(step)
        if self._update_s is not None:
            self.updates.append(self._update_s)
        self.discard()

    def discard(self) -> None:
        """Forget the current step (a warm-up step, or one that fused nothing)."""
        self.current = {}
        self._update_s = None

    def medians_ms(self) -> dict[str, float]:
        """Median ms per stage over the finished steps (a stage not run in a step counts 0)."""
        return {
            stage: statistics.median(s.get(stage, 0.0) for s in self.steps) * 1e3
            if self.steps
            else float("nan")
            for stage in STAGES
        }


@contextmanager
def stage_timers(pipeline: FusionPipeline, clock: StageClock | None = None) -> Iterator[Any]:
    """Time ``pipeline``'s stages inside the block into ``clock`` (None: a new one); its timer
    is put back on the way out, so that a caller can time some steps by stage and leave the
    others as they are."""
    clock = StageClock() if clock is None else clock
    saved = pipeline.timer
    pipeline.timer = clock
    try:
        yield clock
    finally:
        pipeline.timer = saved if saved is not clock else NO_TIMER
