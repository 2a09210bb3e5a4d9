"""server/errors.py: every domain error maps to one status, and the app answers ``{detail}``."""

from __future__ import annotations

import httpx
import pytest
from fastapi import FastAPI
from pydantic import BaseModel, ConfigDict

from skelfuse.calibration.errors import DegenerateGeometry
from skelfuse.calibration.store import CalibrationFileError, UnknownVersion
from skelfuse.protocol.recording_file import RecordingTruncated
from skelfuse.server.app import create_app
from skelfuse.server.errors import (
    AgentRequestFailed,
    Conflict,
    InvalidRequest,
    NotFound,
    SensorUnavailable,
    ServerError,
    error_status,
)
from skelfuse.server.settings import Settings


@pytest.mark.parametrize(
    ("error", "status"),
    [
        (InvalidRequest("x"), 400),
        (NotFound("x"), 404),
        (Conflict("x"), 409),
        (SensorUnavailable("x"), 409),
        (AgentRequestFailed("x"), 502),
        (ServerError("x"), 500),
        (DegenerateGeometry("x"), 400),
        (CalibrationFileError("x"), 400),
        (UnknownVersion("x"), 404),  # a CalibrationError, but the more specific class wins
        (RecordingTruncated("x"), 500),
        (ValueError("x"), 500),
    ],
)
def test_error_status_takes_the_most_specific_mapping(error: Exception, status: int) -> None:
    assert error_status(error) == status


class Point(BaseModel):
    model_config = ConfigDict(allow_inf_nan=False)
    x: float


@pytest.fixture
def app(tmp_path: object) -> FastAPI:
    app = create_app(Settings(data_dir=tmp_path))  # type: ignore[arg-type]

    @app.get("/boom/{kind}")
    async def boom(kind: str) -> None:
        raise {"conflict": Conflict("a run is active; wait"), "version": UnknownVersion("no v9")}[
            kind
        ]

    @app.post("/echo")
    async def echo(point: Point) -> float:
        return point.x

    return app


async def test_the_app_answers_domain_errors_with_their_status_and_message(app: FastAPI) -> None:
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
        conflict = await client.get("/boom/conflict")
        assert conflict.status_code == 409
        assert conflict.json() == {"detail": "a run is active; wait"}
        missing = await client.get("/boom/version")
        assert (missing.status_code, missing.json()) == (404, {"detail": "no v9"})
        body = b'{"x": NaN}'  # Python's JSON reader accepts NaN; the model refuses it
        invalid = await client.post(
            "/echo", content=body, headers={"content-type": "application/json"}
        )
        assert invalid.status_code == 422
        (problem,) = invalid.json()["detail"]
        assert problem["loc"] == ["body", "x"] and problem["input"] == "nan"
