"""A calibration run's record: what was asked (:class:`RunSpec`), where it stands and what it
found (:class:`CalibrationRun`, answered as JSON by ``GET /api/calibration/runs/{id}``).

The service that runs them is ``skelfuse.server.calibration_runs``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from skelfuse.calibration.solvers import PointPairs, SensorResult
from skelfuse.protocol.transform import Matrix4
from skelfuse.server.calibration_run_progress import RunProgress


class RunState(StrEnum):
    CAPTURING = "capturing"
    SOLVING = "solving"
    DONE = "done"
    FAILED = "failed"


@dataclass(frozen=True, slots=True)
class RunSpec:
    method: str
    reference: str
    """A sensor id, or ``world`` (points method only: reference points are world coordinates)."""
    sensors: tuple[str, ...]
    duration_s: float = 15.0
    points: tuple[PointPairs, ...] = ()
    min_overlap: float = 0.3


@dataclass(slots=True)
class CalibrationRun:
    run_id: str
    spec: RunSpec
    created_unix_s: float
    tracker: RunProgress
    """Stage, progress and time left (``skelfuse.server.calibration_run_progress``)."""
    state: RunState = RunState.CAPTURING
    finished_unix_s: float | None = None
    results: dict[str, SensorResult] = field(default_factory=dict)
    floor: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)
    error: str | None = None
    committed_version: int | None = None
    provisional: dict[str, Matrix4] = field(default_factory=dict)
    """While the run is active: poses it has solved so far (after its skeleton stage), which
    viewers use to place the sensors' clouds and bodies before the run ends."""

    @property
    def active(self) -> bool:
        return self.state in (RunState.CAPTURING, RunState.SOLVING)

    @property
    def stage(self) -> str:
        return self.tracker.stage

    @property
    def progress(self) -> float:
        return self.tracker.progress

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.run_id,
            "method": self.spec.method,
            "reference": self.spec.reference,
            "sensors": list(self.spec.sensors),
            "state": str(self.state),
            **self.tracker.to_json(),  # stage, stage_index, stages, progress, eta_s, ...
            "created_unix_s": self.created_unix_s,
            "finished_unix_s": self.finished_unix_s,
            "results": {k: v.to_json() for k, v in sorted(self.results.items())},
            "floor": self.floor,
            "warnings": self.warnings,
            "error": self.error,
            "committed_version": self.committed_version,
        }
