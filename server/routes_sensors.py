"""REST for setting sensors up: one sensor's depth cloud and its latest raw bodies, each in the
world when the sensor has a pose (the active calibration, or a running calibration's provisional
one once its skeleton stage solved) and in its own frame otherwise (docs/api.md).

The cloud is asked of the sensor's agent on request, downsampled by the agent to ``max_points``
and shared between viewers (:class:`skelfuse.server.depth_clouds.LatestClouds`); the bodies are
the newest frame the server holds. Both show people, so both need the API token when one is set
(``server/security.py``).
"""

from __future__ import annotations

import asyncio
from typing import Any, Final, Literal, cast

import numpy as np
import numpy.typing as npt
import orjson
from fastapi import APIRouter, Query, Request, Response
from pydantic import BaseModel, Field

from skelfuse.fusion.sensors import SensorState
from skelfuse.fusion.spaces import cloud_at
from skelfuse.protocol.transform import Matrix4, apply
from skelfuse.server.calibration_runs import CalibrationService
from skelfuse.server.depth_clouds import LatestClouds
from skelfuse.server.errors import CloudUnavailable, NotFound, SensorUnavailable, error_responses
from skelfuse.server.hub import FusionHub

router = APIRouter(prefix="/api/sensors", tags=["sensors"])

DEFAULT_CLOUD_POINTS: Final = 2_000
MAX_CLOUD_POINTS: Final = 20_000
"""Bounded so one answer stays small (about 0.4 MB of JSON)."""
ENCODE_CHUNK: Final = 2_000
"""Points encoded at a time, the event loop free in between: 20,000 points at once took orjson
12-24 ms at load 7-14 on the 2-core test machine (over the loop's 20 ms budget); 2,000 take
0.5 ms."""


Xyz = tuple[float, float, float]


class CloudBody(BaseModel):
    """``GET /api/sensors/{id}/cloud`` (documentation of the answer)."""

    sensor_id: str
    frame: Literal["world", "sensor"] = Field(
        description="world when the sensor has a pose (see pose), else its own camera frame"
    )
    t_capture: float = Field(
        description="capture time, Unix seconds on the server's clock (the agent's stamp "
        "mapped with its clock offset; when the agent sends none, when the answer arrived)"
    )
    count: int
    pose: str | None = Field(
        description="where the pose comes from: stored, sim_truth, manual, provisional (a "
        "running calibration's), or null (sensor frame)"
    )
    points: list[Xyz] = Field(description="metres, 1 mm resolution")


class RawBody(BaseModel):
    tracking_id: str
    states: list[int]
    joints: list[Xyz | None] = Field(description="25 joints, sensor frame, metres")
    joints_world: list[Xyz | None] | None = Field(description="the same in the world")


class BodiesBody(BaseModel):
    """``GET /api/sensors/{id}/bodies`` (documentation of the answer)."""

    sensor_id: str
    connected: bool
    t_capture: float | None
    pose: str | None
    T_world_from_sensor: list[list[float]] | None
    bodies: list[RawBody]


def _sensor(request: Request, sensor_id: str) -> SensorState:
    """The known sensor with this id.

    Raises:
        NotFound: no agent with that id has ever connected.
    """
    hub: FusionHub = request.app.state.hub
    sensor = hub.sensors.get(sensor_id)
    if sensor is None:
        known = ", ".join(sorted(hub.sensors)) or "none"
        raise NotFound(f"no sensor {sensor_id!r} has connected (known: {known})")
    return sensor


def _pose(request: Request, sensor_id: str) -> tuple[Matrix4 | None, str | None]:
    service: CalibrationService = request.app.state.calibration
    pose, source = service.viewer_pose(sensor_id)
    return pose, (source if pose is not None else None)


def _json(content: dict[str, Any], tail: bytes = b"") -> Response:
    """``content`` encoded by orjson straight from numpy (10x quicker than json), ``tail``
    (``,"key":value`` JSON text) spliced in as its last members."""
    body = orjson.dumps(content, option=orjson.OPT_SERIALIZE_NUMPY)
    return Response(body[:-1] + tail + b"}" if tail else body, media_type="application/json")


async def _points_json(points: npt.NDArray[np.float64]) -> bytes:
    """(N, 3) as a JSON array of [x, y, z], encoded :data:`ENCODE_CHUNK` points at a time with
    the event loop free in between."""
    parts = []
    for start in range(0, len(points), ENCODE_CHUNK):
        chunk = points[start : start + ENCODE_CHUNK]
        parts.append(orjson.dumps(chunk, option=orjson.OPT_SERIALIZE_NUMPY)[1:-1])  # no brackets
        await asyncio.sleep(0)
    return b"[" + b",".join(parts) + b"]"


@router.get(
    "/{sensor_id}/cloud",
    responses={
        200: {"model": CloudBody, "description": "the cloud, downsampled"},
        **error_responses(NotFound, SensorUnavailable, CloudUnavailable),
    },
)
async def cloud(
    sensor_id: str,
    request: Request,
    max_points: int = Query(
        DEFAULT_CLOUD_POINTS,
        ge=1,
        le=MAX_CLOUD_POINTS,
        description="at most this many points, spread evenly over the sensor's view",
    ),
) -> Response:
    """The sensor's depth point cloud now, downsampled: ``{"sensor_id", "frame" ("world" or
    "sensor"), "t_capture" (Unix s, server clock), "points" [[x, y, z], ...] metres, "count",
    "pose"}``. Asked of the agent (a cloud under 0.5 s old is shared between callers)."""
    sensor = _sensor(request, sensor_id)
    if not sensor.connected:
        raise SensorUnavailable(f"sensor {sensor_id!r} is offline: start its agent and retry")
    clouds: LatestClouds = request.app.state.clouds
    captured = await clouds.cloud(sensor_id, max_points)
    points = captured.at_most(max_points)
    pose, source = _pose(request, sensor_id)
    if pose is not None and sensor.moving:  # a moving camera's cloud: into its space first
        try:
            points = cloud_at(sensor, captured.t_capture_s, points)
        except ValueError:  # where it looked then is not known: shown in its own frame
            pose, source = None, None
    if pose is not None:
        points = apply(pose, points)
    header = {
        "sensor_id": sensor_id,
        "frame": "sensor" if pose is None else "world",
        "t_capture": round(captured.t_capture_s, 6),
        "count": len(points),
        "pose": source,
    }
    return _json(header, b',"points":' + await _points_json(np.round(points, 3)))


def _rows(joints: npt.NDArray[np.float64]) -> list[list[float] | None]:
    """(25, 3) metres as JSON rows, 0.1 mm, ``None`` where a coordinate is not finite."""
    finite = cast(list[bool], np.isfinite(joints).all(axis=1).tolist())
    rounded = np.round(joints, 4).tolist()
    return [row if ok else None for row, ok in zip(rounded, finite, strict=True)]


@router.get(
    "/{sensor_id}/bodies",
    responses={200: {"model": BodiesBody, "description": "the newest frame's bodies"},
               **error_responses(NotFound)},
)  # fmt: skip
async def bodies(sensor_id: str, request: Request) -> Response:
    """The sensor's newest frame of bodies as it sent them: per body ``tracking_id`` (a string),
    ``states`` (0 not tracked, 1 inferred, 2 tracked), ``joints`` in the sensor's frame and
    ``joints_world`` (null without a pose); ``t_capture`` null before any frame."""
    sensor = _sensor(request, sensor_id)
    pose, source = _pose(request, sensor_id)
    latest = sensor.frames[-1] if sensor.frames else None
    rows = []
    for body in latest.frame.bodies if latest is not None else ():
        joints = np.asarray(body.joints_m, dtype=np.float64)
        rows.append(
            {
                "tracking_id": str(body.tracking_id),
                "states": body.states.tolist(),
                "joints": _rows(joints),
                "joints_world": None if pose is None else _rows(apply(pose, joints)),
            }
        )
    return _json(
        {
            "sensor_id": sensor_id,
            "connected": sensor.connected,
            "t_capture": None if latest is None else round(latest.t_server_s, 6),
            "pose": source,
            "T_world_from_sensor": None if pose is None else np.round(pose, 9),
            "bodies": rows,
        }
    )
