"""REST for recordings: start, stop, list, download (``docs/recording.md``).

One recording at a time. While it runs, the hub hands every accepted ``hello`` and ``frame`` to
the recorder (``FusionHub.start_tap``) with the raw wire bytes; the file's header holds the
calibration active at the start and the sensors then known, and each sensor already online gets
a ``hello`` record rebuilt from its session, so the file replays on its own. A moving sensor's
rebuilt ``hello`` says so (``moving``, ``pose_space``), its frames keep their poses (wire bytes),
and its space's stored transform is in the header under ``space:<id>``.
"""

from __future__ import annotations

import asyncio
import json
import re
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field, StrictStr

from skelfuse import __version__
from skelfuse.protocol.recording_file import (
    FILE_SUFFIX,
    SPACE_KEY_PREFIX,
    Header,
    RecordingError,
    SensorPose,
    summarize,
)
from skelfuse.protocol.wire import Hello, encode
from skelfuse.recording.recorder import Recorder
from skelfuse.server.errors import Conflict, NotFound, error_responses
from skelfuse.server.hub import FusionHub

router = APIRouter(prefix="/api/recordings", tags=["recordings"])
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")


class StartBody(BaseModel):
    name: StrictStr | None = Field(default=None, max_length=64, description="a label for the take")


def _folder(request: Request) -> Path:
    folder: Path = Path(request.app.state.settings.data_dir) / "recordings"
    return folder


def _hub(request: Request) -> FusionHub:
    hub: FusionHub = request.app.state.hub
    return hub


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-.")[:40]


def _header_from_hub(hub: FusionHub, name: str) -> Header:
    calibration: dict[str, SensorPose] = {}
    sensors: dict[str, dict[str, Any]] = {}
    for sensor_id, sensor in sorted(hub.sensors.items()):
        pose, state = hub.pose_of(sensor_id)
        sensors[sensor_id] = {"type": sensor.sensor_type, "pose_state": state}
        if sensor.moving and sensor.pose_space is not None:  # its pose is its space's
            sensors[sensor_id]["pose_space"] = sensor.pose_space
            space = hub.calibration.spaces.get(sensor.pose_space) if hub.calibration else None
            if pose is not None and state == "stored" and space is not None:
                key = SPACE_KEY_PREFIX + sensor.pose_space
                calibration[key] = SensorPose(pose, space.method, state)
            continue
        if pose is not None and state == "stored":
            entry = hub.calibration.sensors[sensor_id] if hub.calibration else None
            if entry is None:
                calibration[sensor_id] = SensorPose(pose, "stored", state)
            else:  # its clock lag too, so a replay places its frames as the live server did
                calibration[sensor_id] = SensorPose(pose, entry.method, state, entry.lag_s)
    return Header(time.time(), __version__, name, calibration, sensors)


def _entry(recording_id: str, path: Path, active: Recorder | None) -> dict[str, Any]:
    if active is not None:
        stats = active.stats()
        return {
            "id": recording_id,
            "state": "failed" if stats.error else "recording",
            "error": stats.error,
            "size_bytes": stats.bytes_written,
            "duration_s": round(stats.duration_s, 3),
            "frames": stats.frames,
            "sensors": list(stats.sensors),
            "name": active.header.name,
            "created_unix_s": active.header.created_unix_s,
        }
    sidecar = path.with_suffix(".json")
    try:
        info: dict[str, Any] = json.loads(sidecar.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        info = _scan(recording_id, path)
    info["size_bytes"] = path.stat().st_size
    return info


def _scan(recording_id: str, path: Path) -> dict[str, Any]:
    """Summary of a file without a sidecar (the server stopped while recording)."""
    try:
        summary = summarize(path)
    except RecordingError as exc:
        return {"id": recording_id, "state": "unreadable", "error": str(exc), "sensors": [],
                "duration_s": 0.0, "frames": 0}  # fmt: skip
    info: dict[str, Any] = {
        "id": recording_id,
        "state": "complete" if summary.complete else "truncated",
        "error": None,
        "duration_s": round(summary.duration_s, 3),
        "frames": summary.frames,
        "sensors": list(summary.sensors),
    }
    path.with_suffix(".json").write_text(json.dumps(info), encoding="utf-8")
    return info


def _active(request: Request) -> tuple[str, Recorder] | None:
    active: tuple[str, Recorder] | None = getattr(request.app.state, "recording", None)
    return active


@router.post("", status_code=201, responses=error_responses(Conflict, RecordingError))
async def start_recording(request: Request, body: StartBody | None = None) -> dict[str, Any]:
    """Start recording every agent's stream; 409 if a recording is already running."""
    if _active(request) is not None:
        raise Conflict("a recording is already running; stop it first")
    hub = _hub(request)
    name = (body.name if body else None) or ""
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    recording_id = f"{stamp}-{_slug(name)}" if _slug(name) else stamp
    folder = _folder(request)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{recording_id}{FILE_SUFFIX}"
    suffix = 1
    while path.exists():
        suffix += 1
        path = folder / f"{recording_id}-{suffix}{FILE_SUFFIX}"
    recording_id = path.stem
    recorder = Recorder(path, _header_from_hub(hub, name))
    now = time.time()
    for sensor_id, sensor in sorted(hub.sensors.items()):
        if sensor.connected:
            hello = Hello(sensor_id, sensor.sensor_type, sensor.agent_version,
                          sensor.nominal_fps, 0, pose_hint=sensor.pose_hint,
                          pose_hint_source=sensor.pose_hint_source, moving=sensor.moving,
                          pose_space=sensor.pose_space)  # fmt: skip
            recorder.on_hello(sensor_id, encode(hello), now)
    hub.start_tap(recorder)
    request.app.state.recording = (recording_id, recorder)
    return _entry(recording_id, path, recorder)


@router.post("/{recording_id}/stop", responses=error_responses(NotFound))
async def stop_recording(request: Request, recording_id: str) -> dict[str, Any]:
    """Stop the running recording (404 if that id is not the one running)."""
    active = _active(request)
    if active is None or active[0] != recording_id:
        raise NotFound(f"recording {recording_id!r} is not running")
    _hub(request).stop_tap()
    request.app.state.recording = None
    _, recorder = active
    stats = await asyncio.to_thread(recorder.close)
    info = {
        "id": recording_id,
        "state": "failed" if stats.error else "complete",
        "error": stats.error,
        "duration_s": round(stats.duration_s, 3),
        "frames": stats.frames,
        "sensors": list(stats.sensors),
        "name": recorder.header.name,
        "created_unix_s": recorder.header.created_unix_s,
    }
    recorder.path.with_suffix(".json").write_text(json.dumps(info), encoding="utf-8")
    info["size_bytes"] = recorder.path.stat().st_size
    return info


@router.get("")
async def list_recordings(request: Request) -> dict[str, Any]:
    """Every recording in the data folder, newest first, with size, duration, sensors, state."""
    folder = _folder(request)
    active = _active(request)
    paths = sorted(folder.glob(f"*{FILE_SUFFIX}"), reverse=True) if folder.is_dir() else []

    def entries() -> list[dict[str, Any]]:
        return [
            _entry(p.stem, p, active[1] if active and active[0] == p.stem else None) for p in paths
        ]

    return {"recordings": await asyncio.to_thread(entries)}


@router.get(
    "/{recording_id}/download",
    response_class=FileResponse,
    responses={
        200: {
            "description": "the recording file (docs/recording.md)",
            "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}}
            },
        },
        **error_responses(NotFound),
    },
)
async def download_recording(request: Request, recording_id: str) -> FileResponse:
    if not _ID.match(recording_id):
        raise NotFound("no such recording")
    path = _folder(request) / f"{recording_id}{FILE_SUFFIX}"
    if not path.is_file():
        raise NotFound(f"no recording {recording_id!r}")
    return FileResponse(
        path, media_type="application/octet-stream", filename=f"{recording_id}{FILE_SUFFIX}"
    )
