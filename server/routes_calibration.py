"""REST for calibration: runs, commit, the active version, history, rollback, export/import.

Bad input is refused with a 4xx whose ``detail`` says what to do (the routes raise the server's
errors, ``server/errors.py`` answers them); nothing is half-applied: a run's result only reaches
fusion through an explicit commit, which writes a new version.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictFloat,
    StrictStr,
    field_validator,
)

from skelfuse.calibration.solvers import PointPairs
from skelfuse.calibration.store import Calibration, CalibrationFileError, UnknownVersion
from skelfuse.server.calibration_run import RunSpec
from skelfuse.server.calibration_runs import CalibrationService
from skelfuse.server.errors import (
    Conflict,
    InvalidRequest,
    NotFound,
    SensorUnavailable,
    error_responses,
)

router = APIRouter(prefix="/api/calibration", tags=["calibration"])

# Strict numbers and strings: what the schema says is what is taken ("1.5" is not a number,
# true is not 1; issue 12's fuzzing). Arrays still become tuples.
Point = tuple[StrictFloat, StrictFloat, StrictFloat]


def _not_bool_or_text(value: object) -> object:
    """JSON Schema's integer: 3 and 3.0, but not true or "3".

    Raises:
        ValueError: a boolean or a string.
    """
    if isinstance(value, bool | str):
        raise ValueError("must be an integer")
    return value


JsonInt = Annotated[int, BeforeValidator(_not_bool_or_text)]


class PointPair(BaseModel):
    model_config = ConfigDict(allow_inf_nan=False, extra="forbid")
    sensor: Point = Field(description="the point in the sensor's camera frame (metres)")
    reference: Point = Field(
        description="the same point in the reference sensor's frame, or in the world when "
        "reference is 'world' (metres)"
    )


class SensorPoints(BaseModel):
    model_config = ConfigDict(allow_inf_nan=False, extra="forbid")
    sensor: StrictStr
    pairs: list[PointPair] = Field(max_length=1000)


_NEEDS = {
    "sensor": ("sensor", {"type": "string"}),
    "points": ("points", {"type": "array", "minItems": 1}),
}
_METHOD_NEEDS: list[Any] = [
    {
        "if": {"properties": {"method": {"const": method}}, "required": ["method"]},
        "then": {"required": [field], "properties": {field: schema}},
    }
    for method, (field, schema) in _NEEDS.items()
]
"""Method ``sensor`` needs ``sensor``, method ``points`` needs ``points``: published in the
schema (issue 12: requests the schema allowed were refused); the route still answers 400."""


class RunRequest(BaseModel):
    """Start a calibration run."""

    model_config = ConfigDict(
        allow_inf_nan=False, extra="forbid", json_schema_extra={"allOf": _METHOD_NEEDS}
    )
    method: Literal["auto", "skeleton", "points", "icp", "sensor"] = "auto"
    reference: StrictStr | None = Field(
        None,
        description="sensor whose frame anchors the world (default: the first sensor by id); "
        "'world' for points given in world coordinates",
    )
    sensors: list[StrictStr] | None = Field(
        None, description="sensors to calibrate (default: every connected sensor)"
    )
    sensor: StrictStr | None = Field(
        None,
        description="method sensor: the one sensor to re-solve against the others (a bumped "
        "one), whose poses stay",
    )
    duration_s: StrictFloat = Field(15.0, ge=3.0, le=120.0, description="skeleton capture time")
    points: list[SensorPoints] | None = Field(None, description="method points: the pairs")
    min_overlap: StrictFloat = Field(
        0.3, gt=0.0, le=1.0, description="icp: warn below this overlap"
    )


Row = Annotated[list[StrictFloat], Field(min_length=4, max_length=4)]


class ImportedIntrinsics(BaseModel):
    """An RGB camera's intrinsics (calibration.camera.CameraIntrinsics), pixels."""

    model_config = ConfigDict(allow_inf_nan=False)
    width: JsonInt = Field(gt=0)
    height: JsonInt = Field(gt=0)
    fx: StrictFloat = Field(gt=0)
    fy: StrictFloat = Field(gt=0)
    cx: StrictFloat
    cy: StrictFloat
    distortion: list[StrictFloat] = Field(
        default_factory=list, description="OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6]]: 0, 4, 5 or 8"
    )


class ImportedSensor(BaseModel):
    """One sensor of an exported calibration file."""

    model_config = ConfigDict(allow_inf_nan=False)
    T_world_from_sensor: Annotated[list[Row], Field(min_length=4, max_length=4)] = Field(
        description="a rigid transform, row-major, metres, last row 0 0 0 1 (else 400)"
    )
    method: StrictStr = "unknown"
    residual_mm: StrictFloat | None = None
    details: dict[str, Any] = Field(default_factory=dict)
    intrinsics: ImportedIntrinsics | None = Field(
        None, description="an RGB camera's intrinsics (a principal point outside the image: 400)"
    )
    lag_s: StrictFloat | None = Field(
        None, description="how late the sensor's clock shows events, seconds"
    )

    @field_validator("details")
    @classmethod
    def _finite(cls, details: dict[str, Any]) -> dict[str, Any]:
        """No NaN or infinity (Python's JSON reader takes them; no JSON answer could carry them).

        Raises:
            ValueError: a non-finite number somewhere in ``details`` (a 422).
        """
        if not _all_finite(details):
            raise ValueError("details must not hold NaN or infinite numbers")
        return details


def _all_finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_all_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_all_finite(v) for v in value)
    return True


class ImportedSpace(BaseModel):
    """One tracking space of an exported calibration file (moving sensors share it)."""

    model_config = ConfigDict(allow_inf_nan=False)
    T_world_from_space: Annotated[list[Row], Field(min_length=4, max_length=4)] = Field(
        description="a rigid transform, row-major, metres, last row 0 0 0 1 (else 400)"
    )
    method: StrictStr = "unknown"
    residual_mm: StrictFloat | None = None
    details: dict[str, Any] = Field(default_factory=dict)

    @field_validator("details")
    @classmethod
    def _finite(cls, details: dict[str, Any]) -> dict[str, Any]:
        """As :meth:`ImportedSensor._finite`.

        Raises:
            ValueError: a non-finite number somewhere in ``details`` (a 422).
        """
        if not _all_finite(details):
            raise ValueError("details must not hold NaN or infinite numbers")
        return details


class CalibrationFile(BaseModel):
    """A file from ``GET /api/calibration/export`` (format 1), typed so that what the schema
    allows is what the import takes (issue 12); only rigidity is checked beyond it (400)."""

    model_config = ConfigDict(allow_inf_nan=False)
    format: Literal[1]  # calibration.store.FORMAT_VERSION
    version: JsonInt = 0
    created_unix_s: StrictFloat = 0.0
    note: StrictStr = ""
    sensors: dict[str, ImportedSensor] = Field(default_factory=dict)
    spaces: dict[str, ImportedSpace] = Field(
        default_factory=dict, description="tracking spaces' transforms (docs/calibration.md)"
    )


class RollbackRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    version: JsonInt = Field(ge=1)


def _service(request: Request) -> CalibrationService:
    service: CalibrationService = request.app.state.calibration
    return service


def calibration_json(calibration: Calibration | None) -> dict[str, Any]:
    if calibration is None:
        return {"version": None, "created_unix_s": None, "note": "", "sensors": {}}
    return calibration.to_json()


@router.post(
    "/runs", status_code=202, responses=error_responses(InvalidRequest, Conflict, SensorUnavailable)
)
async def start_run(body: RunRequest, request: Request) -> dict[str, Any]:
    """Start a run (``auto`` by default). Poll ``GET /api/calibration/runs/{id}``."""
    service = _service(request)
    hub = service.hub
    sensors: tuple[str, ...]
    if body.method == "sensor":
        if body.sensor is None:
            raise InvalidRequest("method sensor needs 'sensor': the sensor to re-solve")
        sensors = (body.sensor,)
    elif body.sensors is not None:
        sensors = tuple(dict.fromkeys(body.sensors))
    elif body.method == "points":
        sensors = tuple(dict.fromkeys(p.sensor for p in body.points or ()))
    else:
        sensors = tuple(sorted(s for s, state in hub.sensors.items() if state.connected))
    if not sensors:
        raise Conflict("no sensors to calibrate: connect at least one agent")
    reference = sensors[0] if body.method == "sensor" else body.reference or sensors[0]
    points = tuple(
        PointPairs(
            entry.sensor,
            np.array([p.sensor for p in entry.pairs], dtype=np.float64).reshape(-1, 3),
            np.array([p.reference for p in entry.pairs], dtype=np.float64).reshape(-1, 3),
        )
        for entry in body.points or ()
    )
    spec = RunSpec(body.method, reference, sensors, body.duration_s, points, body.min_overlap)
    return service.start(spec).to_json()


@router.get("/runs")
async def list_runs(request: Request) -> dict[str, Any]:
    runs = sorted(_service(request).runs.values(), key=lambda r: r.created_unix_s)
    return {"runs": [r.to_json() for r in runs]}


@router.get("/runs/{run_id}", responses=error_responses(NotFound))
async def get_run(run_id: str, request: Request) -> dict[str, Any]:
    return _service(request).run(run_id).to_json()


@router.post("/runs/{run_id}/commit", responses=error_responses(NotFound, Conflict))
async def commit_run(run_id: str, request: Request) -> dict[str, Any]:
    """Make the run's result the active calibration (a new version); fusion uses it at once."""
    return calibration_json(await _service(request).commit(run_id))


@router.get("")
async def active(request: Request) -> dict[str, Any]:
    """The active stored calibration, plus what fusion uses for every known sensor."""
    service = _service(request)
    effective = {}
    for sensor_id in sorted(service.hub.sensors):
        pose, state = service.hub.pose_of(sensor_id)
        effective[sensor_id] = {
            "state": state,
            "T_world_from_sensor": None if pose is None else pose.tolist(),
        }
    return {**calibration_json(service.hub.calibration), "effective": effective}


@router.get("/history")
async def history(request: Request) -> dict[str, Any]:
    service = _service(request)
    active_version = service.hub.calibration.version if service.hub.calibration else None
    return {
        "active": active_version,
        "versions": [
            {
                "version": c.version,
                "created_unix_s": c.created_unix_s,
                "note": c.note,
                "sensors": {
                    k: {"method": v.method, "residual_mm": v.residual_mm}
                    for k, v in sorted(c.sensors.items())
                },
            }
            for c in await service.history()
        ],
    }


@router.post("/rollback", responses=error_responses(UnknownVersion))
async def rollback(body: RollbackRequest, request: Request) -> dict[str, Any]:
    """Make an earlier version active again (saved as a new version)."""
    return calibration_json(await _service(request).rollback(body.version))


@router.get("/export", responses=error_responses(NotFound))
async def export(request: Request) -> JSONResponse:
    calibration = _service(request).hub.calibration
    if calibration is None:
        raise NotFound("nothing to export: no calibration has been committed yet")
    return JSONResponse(
        calibration.to_json(),
        headers={
            "Content-Disposition": f'attachment; filename="calibration-v{calibration.version}.json"'
        },
    )


@router.post("/import", responses=error_responses(CalibrationFileError))
async def import_calibration(request: Request, body: CalibrationFile) -> dict[str, Any]:
    """Validate an exported calibration and make it active (a new version)."""
    return calibration_json(await _service(request).import_json(body.model_dump()))
