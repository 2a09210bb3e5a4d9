"""Where one fused frame's time goes: wall time per pipeline stage, measured in the bench only.

The library holds no timing code: :func:`stage_timers` wraps, for the duration of a ``with``
block, the module-level functions ``skelfuse.fusion.pipeline`` calls (looked up there at call
time, so replacing the module attribute reaches them) and two methods of one pipeline
instance. Each wrapper adds the seconds spent inside it to its stage for the current step.

Stages (docs/fusion.md numbering):

- ``views_at``: steps 1–2, each sensor's bodies at the instant, in the world frame (with a
  sensor late at the deadline, ``views_with_late`` in the engine, which carries it forward);
- ``associate``: step 3, ``PersonTracker.associate``;
- ``labels``: step 4, ``label_views``;
- ``confidence + fusion``: steps 5–6, from the end of the mirror labels (of the association,
  when labels are off) to the start of the bone observation: the confidence terms, the fusions,
  joint confidence and carriers (and with labels off, the batch build before them);
- ``bones observe``: ``observe_bone_lengths``;
- ``walking check``: ``FusionPipeline._check_walking_directions``, all persons;
- ``filter``: step 7, ``filter_all``;
- ``bone fit``: step 8, ``fit_bone_lengths``;
- ``other``: the rest of ``fuse_step`` (grid bookkeeping, batch build, track moves, building
  the output persons, confirming tracks).

Wrappers cost ~0.3 µs per call and about ten run a step: at 4 sensors × 6 people, measured
interleaved on 2026-11-24, a step timed with them took ~1.03× one without. So
``bench/fusion_timing.py`` times one step in three by stage (:func:`stage_timers` around it
alone) and takes the step's own figures from the other two, which run the library as it is.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

STAGES = (
    "views_at",
    "associate",
    "labels",
    "confidence + fusion",
    "bones observe",
    "walking check",
    "filter",
    "bone fit",
    "other",
)
_MODULE_STAGES = {
    "views_at": "views_at",
    "label_views": "labels",
    "observe_bone_lengths": "bones observe",
    "filter_all": "filter",
    "fit_bone_lengths": "bone fit",
}

_ENGINE_STAGES = {"views_with_late": "views_at"}
"""What ``skelfuse.fusion.engine`` calls instead of the pipeline's step when a sensor is late."""

_WALKING_CHECKS = ("_check_walking_directions", "_check_walking_direction")
"""The pipeline's walking check, all persons at once (or, before that, one by one)."""


class StageClock:
    """Seconds per stage of the current step, and every finished step's figures."""

    def __init__(self) -> None:
        self.current: dict[str, float] = {}
        self.steps: list[dict[str, float]] = []
        self.updates: list[float] = []
        """Seconds in ``FusionPipeline.update`` (steps 3–8) per finished step that ran it."""
        self._update_s: float | None = None
        self._fusion_from: float | None = None

    def add(self, stage: str, seconds: float) -> None:
        self.current[stage] = self.current.get(stage, 0.0) + seconds

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
        self._fusion_from = None

    def wrap_update(self, update: Callable[..., Any]) -> Callable[..., Any]:
        """``update`` (the pipeline's steps 3–8) timed as a whole, apart from the stages."""

        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return update(*args, **kwargs)
            finally:
                self._update_s = time.perf_counter() - start

        return timed

    def medians_ms(self) -> dict[str, float]:
        """Median ms per stage over the finished steps (a stage not run in a step counts 0)."""
        return {
            stage: statistics.median(s.get(stage, 0.0) for s in self.steps) * 1e3
            if self.steps
            else float("nan")
            for stage in STAGES
        }

    def wrap(self, stage: str, function: Callable[..., Any]) -> Callable[..., Any]:
        """``function`` timed into ``stage``; the labels and association mark where steps 5–6
        begin, the bone observation where they end."""

        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            if stage == "bones observe" and self._fusion_from is not None:
                self.add("confidence + fusion", start - self._fusion_from)
                self._fusion_from = None
            try:
                return function(*args, **kwargs)
            finally:
                end = time.perf_counter()
                self.add(stage, end - start)
                if stage in ("associate", "labels"):
                    self._fusion_from = end

        return timed


@contextmanager
def stage_timers(pipeline: Any, clock: StageClock | None = None) -> Iterator[StageClock]:
    """Time ``pipeline``'s stages inside the block (module docstring) into ``clock`` (None: a
    new one); restores everything on the way out, so that a caller can time some steps by
    stage and leave the others as they are.

    Args:
        pipeline: a :class:`skelfuse.fusion.pipeline.FusionPipeline`.
    """
    from skelfuse.fusion import engine, pipeline as module

    clock = StageClock() if clock is None else clock
    saved = {name: getattr(module, name) for name in _MODULE_STAGES if hasattr(module, name)}
    saved_engine = {name: getattr(engine, name) for name in _ENGINE_STAGES if hasattr(engine, name)}
    try:
        for name, function in saved.items():
            setattr(module, name, clock.wrap(_MODULE_STAGES[name], function))
        for name, function in saved_engine.items():
            setattr(engine, name, clock.wrap(_ENGINE_STAGES[name], function))
        pipeline.tracker.associate = clock.wrap("associate", pipeline.tracker.associate)
        pipeline.update = clock.wrap_update(pipeline.update)
        for name in _WALKING_CHECKS:
            if hasattr(pipeline, name):
                setattr(pipeline, name, clock.wrap("walking check", getattr(pipeline, name)))
        yield clock
    finally:
        for name, function in saved.items():
            setattr(module, name, function)
        for name, function in saved_engine.items():
            setattr(engine, name, function)
        pipeline.tracker.__dict__.pop("associate", None)
        for name in ("update", *_WALKING_CHECKS):
            pipeline.__dict__.pop(name, None)
