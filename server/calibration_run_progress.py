"""A calibration run's stages, its progress over the whole run and the time left
(docs/calibration.md, "Progress").

Each method has a fixed list of stages (:data:`STAGES`). Within a stage, progress comes from
the work itself: the walk from the clock, ICP from the solver process (each sensor, pass and
voxel level done, ``calibration.icp.refine_all``); stages without inner steps (the skeleton
solve, the depth capture) jump when they end.

**Progress over the run.** When a stage starts, the part of the bar still to go is shared among
it and the stages after it in proportion to how long each is expected to take: the walk its
``duration_s``, the others the seconds per unit of work this server *measured* the last time it
ran them (:class:`StageRates`; a unit is a sensor pairing for the skeleton solve, one capture for
the depth, one sensor refinement for ICP), or :data:`PRIOR_S_PER_UNIT` before it ever has. The
bar therefore never goes back: what is done stays done, only the split of what is left moves.

**Time left** (``eta_s``): the current stage's rest from its own measured rate (elapsed / share
done, counting down between reports; blended with the stage's time in the last run while little
is done, in proportion to the share done), plus the later stages at their measured rates; ``null``
while any of them has no measurement (a stage without inner steps before its first run on this
server, a stage not begun yet that never ran here). Never a prior: a guess is not shown as a
time.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from skelfuse.server.clock import Clock

WALK: Final = "walk through the capture area"
SKELETONS: Final = "solving skeleton poses"
DEPTH: Final = "capturing depth clouds"
ICP: Final = "refining with ICP"
POINTS: Final = "solving from points"

STAGES: Final[Mapping[str, tuple[str, ...]]] = {
    "auto": (WALK, SKELETONS, DEPTH, ICP),
    "skeleton": (WALK, SKELETONS),
    "icp": (DEPTH, ICP),
    "sensor": (WALK, SKELETONS, DEPTH, ICP),
    "points": (POINTS,),
}
"""The stages of each method, in order (``stages`` in a run's JSON)."""

PRIOR_S_PER_UNIT: Final[Mapping[str, float]] = {
    WALK: 1.0,  # a unit is one second of the walk: exact
    SKELETONS: 1.0,
    DEPTH: 1.5,
    ICP: 8.0,
    POINTS: 0.01,
}
"""Seconds per unit of work before this server measured a stage: only to split the bar (a
3-sensor auto run on a 2-core machine took about 1 s per pairing, 1-2 s to capture depth and
5-20 s per ICP refinement), never shown as time left."""


class StageRates:
    """Seconds per unit of work each stage took the last time it ran on this server."""

    def __init__(self) -> None:
        self._measured: dict[str, float] = {}

    def measured(self, stage: str) -> float | None:
        return self._measured.get(stage)

    def record(self, stage: str, seconds: float, units: float) -> None:
        if units > 0 and seconds >= 0:
            self._measured[stage] = seconds / units


class RunProgress:
    """Where one run stands: its stage, the share of it done, and the time left.

    Args:
        stages: the run's stages in order (:data:`STAGES`).
        units: work units per stage (seconds of walk, pairings, captures, refinements).
        rates: this server's measured rates, read for the split and the time left, and
            updated as stages end.
        clock: the run's clock (``monotonic`` times the stages).
    """

    def __init__(
        self, stages: tuple[str, ...], units: Mapping[str, float], rates: StageRates, clock: Clock
    ) -> None:
        self.stages = stages
        self._units = dict(units)
        self._rates = rates
        self._clock = clock
        self.index = -1
        """Index of the current stage in ``stages``; -1 before the first, ``len(stages)`` done."""
        self.detail = ""
        self.failed = False
        self._base = 0.0  # progress when the current stage began
        self._share = 0.0  # its part of the bar
        self._fraction = 0.0  # share of the current stage done
        self._began = 0.0  # monotonic start of the current stage
        self._reported = 0.0  # monotonic time of the last fraction reported
        self._measure = True  # record the current stage's time when it ends

    @property
    def stage(self) -> str:
        if self.failed:
            return "failed"
        if self.index >= len(self.stages):
            return "done"
        return self.stages[self.index] if self.index >= 0 else "starting"

    @property
    def progress(self) -> float:
        """Share of the whole run done, 0..1, never decreasing."""
        if self.index >= len(self.stages) and not self.failed:
            return 1.0
        return min(1.0, self._base + self._share * self._fraction)

    def _expected_s(self, stage: str) -> float:
        rate = self._rates.measured(stage)
        return self._units.get(stage, 1.0) * (PRIOR_S_PER_UNIT[stage] if rate is None else rate)

    def enter(self, stage: str, detail: str = "", measure: bool = True) -> None:
        """Start ``stage`` (a later one of ``stages``: skipped ones count as done; the current
        one again: only its detail changes). ``measure``: record how long the stage took for
        the next runs (not when it includes a one-off wait, e.g. the solver process starting)."""
        if 0 <= self.index < len(self.stages) and self.stages[self.index] == stage:
            self.detail = detail
            return
        now = self._clock.monotonic()
        self._end_stage(now)
        self._base = self.progress
        self.index = self.stages.index(stage)
        later = [self._expected_s(s) for s in self.stages[self.index :]]
        total = sum(later)
        self._share = (1.0 - self._base) * (later[0] / total if total > 0 else 1.0)
        self._fraction = 0.0
        self._began = self._reported = now
        self._measure = measure
        self.detail = detail

    def advance(self, fraction: float, detail: str | None = None) -> None:
        """The current stage is ``fraction`` (0..1) done; a smaller value than before is kept
        at the larger (progress never goes back)."""
        if 0 <= self.index < len(self.stages) and fraction > self._fraction:
            self._fraction = min(1.0, fraction)
            self._reported = self._clock.monotonic()
        if detail is not None:
            self.detail = detail

    def finish(self) -> None:
        self._end_stage(self._clock.monotonic())
        self.index = len(self.stages)
        self.detail = ""

    def fail(self) -> None:
        self.failed = True

    def _end_stage(self, now: float) -> None:
        if 0 <= self.index < len(self.stages) and not self.failed and self._measure:
            stage = self.stages[self.index]
            self._rates.record(stage, now - self._began, self._units.get(stage, 1.0))

    def eta_s(self) -> float | None:
        """Seconds left in the run from measured rates; None when one is unknown."""
        if self.failed or self.index >= len(self.stages):
            return 0.0 if not self.failed else None
        if self.index < 0:
            return None
        now = self._clock.monotonic()
        stage = self.stages[self.index]
        rate = self._rates.measured(stage)
        before = None if rate is None else rate * self._units.get(stage, 1.0)
        if self._fraction > 0:
            total = (self._reported - self._began) / self._fraction
            if before is not None:  # little done yet: the last run's time weighs more
                total = self._fraction * total + (1.0 - self._fraction) * before
        elif before is None:
            return None
        else:
            total = before
        left = max(0.0, total - (now - self._began))
        for later in self.stages[self.index + 1 :]:
            rate = self._rates.measured(later)
            if rate is None:
                return None
            left += rate * self._units.get(later, 1.0)
        return left

    def to_json(self) -> dict[str, Any]:
        eta = self.eta_s()
        return {
            "stage": self.stage,
            "stage_index": self.index if self.index >= 0 else 0,
            "stages": list(self.stages),
            "stage_detail": self.detail,
            "stage_progress": 1.0 if self.index >= len(self.stages) else round(self._fraction, 3),
            "progress": round(self.progress, 3),
            "eta_s": None if eta is None else round(eta, 1),
        }
