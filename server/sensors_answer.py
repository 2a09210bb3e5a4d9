"""``GET /api/sensors``'s answer: each sensor's row, with the error fusion has learned for it.

The rows themselves come from the engine (:func:`skelfuse.fusion.sensors.sensor_rows`: session,
health, clock, calibration, drift); this module adds what the person setting up the rig looks
at to decide which sensor to move: ``learned_error``, the RMS 3-D error (mm) of the sensor's
trunk, arm and leg joints as fusion has learned it from the rig's own residuals
(:class:`skelfuse.fusion.rig_errors.RigErrors`), or ``null`` for a sensor fusion has not yet
seen a person through. The models type the answer's new parts in the OpenAPI document; the
engine's fields pass through as they are (``extra="allow"``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from pydantic import BaseModel, ConfigDict, Field

from skelfuse.fusion.rig_errors import SensorErrors


class LearnedError(BaseModel):
    """One sensor's learned error by joint group, as ``/api/sensors`` shows it."""

    trunk_mm: float = Field(
        ge=0, description="RMS 3-D error of the spine, neck, head, shoulder and hip joints, mm"
    )
    arms_mm: float = Field(ge=0, description="RMS 3-D error of the arm and hand joints, mm")
    legs_mm: float = Field(ge=0, description="RMS 3-D error of the knee, ankle and foot joints, mm")
    samples: float = Field(
        ge=0, description="evidence behind it: (forgotten) views of a joint per joint"
    )
    learned: bool = Field(
        description="the evidence outweighs the sensor type's prior (false: the prior's figures)"
    )

    @classmethod
    def of(cls, errors: SensorErrors) -> LearnedError:
        """From :meth:`RigErrors.summary`'s entry; millimetres to 0.1, samples to 0.1."""
        groups = errors.groups_mm
        return cls(
            trunk_mm=round(groups["trunk"], 1),
            arms_mm=round(groups["arms"], 1),
            legs_mm=round(groups["legs"], 1),
            samples=round(errors.samples, 1),
            learned=errors.learned,
        )


class SensorRow(BaseModel):
    """One sensor's row (docs/api.md lists every field; the engine's pass through untyped)."""

    model_config = ConfigDict(extra="allow")

    id: str
    learned_error: LearnedError | None = Field(
        description="the error fusion has learned for this sensor; null until fusion has "
        "seen a person through it"
    )


class SensorsAnswer(BaseModel):
    """``GET /api/sensors``."""

    sensors: list[SensorRow]
    rejected_unregistered: dict[str, int] = Field(
        description="messages from connections that never registered, per reason"
    )


def sensors_answer(
    rows: Sequence[Mapping[str, object]],
    errors: Mapping[str, SensorErrors],
    rejected_unregistered: Mapping[str, int],
) -> SensorsAnswer:
    """The answer from the engine's rows (:meth:`FusionEngine.sensor_summary`), the learned
    errors by sensor id (:meth:`RigErrors.summary`) and the unregistered rejections."""
    sensors = []
    for row in rows:
        learned = errors.get(str(row["id"]))
        error = None if learned is None else LearnedError.of(learned)
        sensors.append(SensorRow.model_validate({**row, "learned_error": error}))
    return SensorsAnswer(sensors=sensors, rejected_unregistered=dict(rejected_unregistered))
