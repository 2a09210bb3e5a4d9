"""The server's errors and the one place that turns them into HTTP responses.

::

    ServerError                 base of the errors the server raises itself (500)
    ├── InvalidRequest          well-formed but unusable: unknown sensors, bad points (400)
    ├── NotFound                no such run, person, recording (404)
    ├── Conflict                not now: another run is active, a sensor is offline (409)
    │   └── SensorUnavailable   the sensor is unknown or offline
    ├── AgentRequestFailed      an agent refused a request, failed, or did not answer (502)
    ├── CloudUnavailable        a viewer's depth cloud: the agent cannot give one now (503)
    └── SolverCrashed           the calibration worker process died mid-solve (500)

Errors of the layers below keep their own classes and are mapped here too (most specific class
wins): ``CalibrationError`` is 400, its ``UnknownVersion`` 404; ``RecordingError`` is 500 (the
data folder failed us, not the request). Routes raise; :func:`error_response`, registered once in
:func:`skelfuse.server.app.create_app`, answers ``{"detail": <the error's message>}``, the
message written for the user. Malformed bodies stay FastAPI's 422 (:func:`invalid_body_response`).

The OpenAPI document is generated from the same mapping: a route lists the errors it raises with
``responses=error_responses(NotFound, Conflict)``, which gives each its status, its class's
description and the :class:`ErrorBody` schema (``server/openapi.py`` adds what every operation of
a kind can answer: 401, 413, 400 for a body that is not JSON, 422).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Final

from fastapi import Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException
from starlette.routing import Match

from skelfuse.calibration.errors import CalibrationError
from skelfuse.calibration.store import UnknownVersion
from skelfuse.protocol.recording_file import RecordingError


class ServerError(Exception):
    """Base class of the server's own errors; ``status`` is the HTTP status it answers with."""

    status: ClassVar[int] = 500


class InvalidRequest(ServerError):
    """The request is well-formed but cannot be used (unknown sensors, degenerate points...)."""

    status = 400


class NotFound(ServerError):
    """The run, person, recording or version named in the request does not exist."""

    status = 404


class Conflict(ServerError):
    """The request is valid but the server's state does not allow it now; retrying later may."""

    status = 409


class SensorUnavailable(Conflict):
    """The sensor is unknown or offline; the message says which."""


class AgentRequestFailed(ServerError):
    """An agent answered a request with an error, or did not answer in time."""

    status = 502


class CloudUnavailable(ServerError):
    """The sensor's agent cannot give a depth cloud now (no depth, busy, or it timed out)."""

    status = 503


class SolverCrashed(ServerError):
    """The process running a calibration solver died (killed, out of memory, a native crash)."""


STATUS_BY_ERROR: Final[dict[type[Exception], int]] = {
    CalibrationError: 400,
    UnknownVersion: 404,
    RecordingError: 500,
}
"""Statuses of the lower layers' errors (the server's own carry theirs in ``status``)."""

HTTP_METHODS: Final = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")
"""The methods a 405's ``Allow`` header may list."""

HANDLED_ERRORS: Final[tuple[type[Exception], ...]] = (ServerError, *STATUS_BY_ERROR)
"""The exception classes :func:`error_response` is registered for."""


class ErrorBody(BaseModel):
    """Every error's body: what went wrong and, where it can, what to do instead."""

    detail: str


def status_of(error: type[Exception]) -> int:
    """The HTTP status of an error class: the most specific mapped class in its MRO wins."""
    if issubclass(error, ServerError):
        return error.status
    for cls in error.__mro__:
        if cls in STATUS_BY_ERROR:
            return STATUS_BY_ERROR[cls]
    return 500


def error_status(exc: Exception) -> int:
    """The HTTP status of a domain error (:func:`status_of` its class)."""
    return status_of(type(exc))


def error_responses(*errors: type[Exception]) -> dict[int | str, dict[str, Any]]:
    """A route's ``responses=`` for the errors it raises: status → description and body schema.

    The description is the first line of each class's docstring; errors sharing a status are
    described together.
    """
    responses: dict[int | str, dict[str, Any]] = {}
    for error in errors:
        status = status_of(error)
        description = (error.__doc__ or error.__name__).strip().splitlines()[0]
        if status in responses:
            responses[status]["description"] += f" Or: {description}"
        else:
            responses[status] = {"model": ErrorBody, "description": description}
    return responses


async def error_response(request: Request, exc: Exception) -> JSONResponse:
    """The response to a domain error raised by a route: its status, ``{"detail": message}``."""
    del request  # the same answer whatever the route
    return JSONResponse(status_code=error_status(exc), content={"detail": str(exc)})


async def invalid_body_response(request: Request, exc: RequestValidationError) -> JSONResponse:
    """422 for a body or query FastAPI could not parse, listing every problem.

    FastAPI echoes the offending input; a NaN in it would make the 422 itself fail to encode, so
    non-finite numbers are sent as their names.
    """
    del request
    detail = _finite_json(jsonable_encoder(exc.errors()))
    return JSONResponse(status_code=422, content={"detail": detail})


async def method_not_allowed_response(request: Request, exc: Exception) -> JSONResponse:
    """405 whose ``Allow`` lists every method of the path, not just those of the first route.

    Starlette answers from the first route whose path matches, so a path served by two routes
    (``PUT`` and ``DELETE /api/bones/default``) would claim to allow only one of them.
    """
    routes = request.app.router.routes  # FastAPI nests included routers: ask each to match
    allowed = [
        method
        for method in HTTP_METHODS
        if any(r.matches({**request.scope, "method": method})[0] is Match.FULL for r in routes)
    ]
    headers = {"Allow": ", ".join(allowed)} if allowed else None
    detail = exc.detail if isinstance(exc, HTTPException) else "Method Not Allowed"
    return JSONResponse({"detail": detail}, status_code=405, headers=headers)


def _finite_json(value: Any) -> Any:
    """Replace NaN and infinities (which JSON cannot carry) by their names as strings."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _finite_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_json(v) for v in value]
    return value
