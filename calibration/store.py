"""Persisted calibration: each sensor's ``T_world_from_sensor``, versioned, crash-safe.

Layout of the data folder::

    calibration.json                 the active version (what the server loads at start-up)
    calibration-history/v000007.json every version ever saved, the active one included

Every save writes a new version. Each file is written to a temporary name, fsync'ed, renamed
over its target and the folder fsync'ed, and the history copy is written before the active
file, so a crash leaves either the old or the new version active, never half of one.
Rolling back re-saves an old version as a new one: history only grows.

A sensor's entry may carry ``intrinsics`` (an RGB camera's, :class:`CameraIntrinsics` 's JSON:
width, height, fx, fy, cx, cy, distortion) and ``lag_s`` (how late its clock shows events,
seconds, from :mod:`calibration.motion_sync`; readers subtract it from the sensor's times).
Both are written only when set, so files without them read and write as before (format 1).

Tracking spaces (moving sensors, docs/calibration.md "Tracking spaces"): ``spaces`` maps a space
id (a ``hello``'s ``pose_space``) to its ``T_world_from_space``; every moving sensor of that space
shares it. Written only when there is one, so files without spaces keep their bytes, and files
from before spaces load with none (still format 1).
"""

from __future__ import annotations

import json
import os
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.calibration.camera import CameraIntrinsics
from skelfuse.calibration.errors import CalibrationError, InvalidInput
from skelfuse.protocol.transform import Matrix4, is_rigid

FILE_NAME = "calibration.json"
HISTORY_DIR = "calibration-history"
FORMAT_VERSION = 1
_HISTORY_FILE = re.compile(r"^v(\d{6,})\.json$")


class CalibrationFileError(CalibrationError):
    """A stored or imported calibration cannot be read; the message says which and why."""


class UnknownVersion(CalibrationError):
    """A version that is not in the history."""


@dataclass(frozen=True, slots=True)
class SensorCalibration:
    """One sensor's pose in the world (4×4 float64, metres) and how it was obtained; an RGB
    camera's intrinsics and a clock lag (seconds) where known."""

    T_world_from_sensor: Matrix4
    method: str
    residual_mm: float | None = None
    details: dict[str, Any] = field(default_factory=dict)
    intrinsics: CameraIntrinsics | None = None
    lag_s: float | None = None

    def to_json(self) -> dict[str, Any]:
        entry: dict[str, Any] = {
            "T_world_from_sensor": self.T_world_from_sensor.tolist(),
            "method": self.method,
            "residual_mm": self.residual_mm,
            "details": self.details,
        }
        if self.intrinsics is not None:
            entry["intrinsics"] = self.intrinsics.to_json()
        if self.lag_s is not None:
            entry["lag_s"] = self.lag_s
        return entry


@dataclass(frozen=True, slots=True)
class SpaceCalibration:
    """One tracking space's pose in the world (``T_world_from_space``, 4×4 float64, metres),
    shared by every moving sensor whose poses are in that space, and how it was obtained."""

    T_world_from_space: Matrix4
    method: str
    residual_mm: float | None = None
    details: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "T_world_from_space": self.T_world_from_space.tolist(),
            "method": self.method,
            "residual_mm": self.residual_mm,
            "details": self.details,
        }


@dataclass(frozen=True, slots=True)
class Calibration:
    version: int
    created_unix_s: float
    sensors: dict[str, SensorCalibration]
    note: str = ""
    spaces: dict[str, SpaceCalibration] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "format": FORMAT_VERSION,
            "version": self.version,
            "created_unix_s": self.created_unix_s,
            "note": self.note,
            "sensors": {sensor_id: s.to_json() for sensor_id, s in sorted(self.sensors.items())},
        }
        if self.spaces:
            data["spaces"] = {space: c.to_json() for space, c in sorted(self.spaces.items())}
        return data

    @staticmethod
    def from_json(data: Any, origin: str) -> Calibration:
        """Parse and validate; raises :class:`CalibrationFileError` naming ``origin``."""
        if not isinstance(data, dict) or data.get("format") != FORMAT_VERSION:
            raise CalibrationFileError(
                f"{origin}: not a skelfuse calibration (expected an object with format "
                f"{FORMAT_VERSION})"
            )
        raw_sensors = data.get("sensors", {})
        if not isinstance(raw_sensors, dict):
            raise CalibrationFileError(f"{origin}: 'sensors' must be an object of sensor ids")
        sensors: dict[str, SensorCalibration] = {}
        for sensor_id, entry in raw_sensors.items():
            if not isinstance(entry, dict):
                raise CalibrationFileError(f"{origin}: sensor {sensor_id!r} must be an object")
            try:
                matrix = np.asarray(entry.get("T_world_from_sensor"), dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise CalibrationFileError(
                    f"{origin}: sensor {sensor_id!r}: T_world_from_sensor is not a 4×4 matrix"
                ) from exc
            if not is_rigid(matrix, atol=1e-5):
                raise CalibrationFileError(
                    f"{origin}: sensor {sensor_id!r}: T_world_from_sensor is not a rigid 4×4 "
                    "transform (row-major, metres, last row 0 0 0 1)"
                )
            residual = entry.get("residual_mm")
            if residual is not None and not isinstance(residual, int | float):
                raise CalibrationFileError(f"{origin}: sensor {sensor_id!r}: bad residual_mm")
            details = entry.get("details", {})
            intrinsics = None
            if entry.get("intrinsics") is not None:
                try:
                    intrinsics = CameraIntrinsics.from_json(
                        entry["intrinsics"], f"{origin}: sensor {sensor_id!r}"
                    )
                except InvalidInput as exc:
                    raise CalibrationFileError(str(exc)) from exc
            lag = entry.get("lag_s")
            if lag is not None and (not isinstance(lag, int | float) or not np.isfinite(lag)):
                raise CalibrationFileError(f"{origin}: sensor {sensor_id!r}: bad lag_s")
            sensors[str(sensor_id)] = SensorCalibration(
                matrix,
                str(entry.get("method", "unknown")),
                None if residual is None else float(residual),
                details if isinstance(details, dict) else {},
                intrinsics,
                None if lag is None else float(lag),
            )
        version = data.get("version", 0)
        created = data.get("created_unix_s", 0.0)
        if not isinstance(version, int) or not isinstance(created, int | float):
            raise CalibrationFileError(f"{origin}: bad version or created_unix_s")
        spaces = _spaces_from_json(data.get("spaces", {}), origin)
        return Calibration(version, float(created), sensors, str(data.get("note", "")), spaces)


class CalibrationStore:
    """Reads and writes the calibration in one data folder."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)

    @property
    def path(self) -> Path:
        return self.data_dir / FILE_NAME

    @property
    def history_dir(self) -> Path:
        return self.data_dir / HISTORY_DIR

    def load(self) -> Calibration | None:
        """The active calibration, or None if none was ever saved."""
        return self._read(self.path)

    def _read(self, path: Path) -> Calibration | None:
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CalibrationFileError(f"{path}: not valid JSON ({exc})") from exc
        return Calibration.from_json(data, str(path))

    def versions(self) -> list[int]:
        """Every saved version number, oldest first."""
        if not self.history_dir.is_dir():
            return []
        found = (_HISTORY_FILE.match(p.name) for p in self.history_dir.iterdir())
        return sorted(int(m.group(1)) for m in found if m)

    def get(self, version: int) -> Calibration:
        calibration = self._read(self.history_dir / f"v{version:06d}.json")
        if calibration is None:
            raise UnknownVersion(
                f"calibration version {version} does not exist (saved: {self.versions() or 'none'})"
            )
        return calibration

    def history(self) -> list[Calibration]:
        return [self.get(v) for v in self.versions()]

    def save(
        self,
        sensors: dict[str, SensorCalibration],
        note: str = "",
        spaces: dict[str, SpaceCalibration] | None = None,
    ) -> Calibration:
        """Write a new version atomically, make it active, and return it.

        ``spaces``: the tracking spaces of the new version; None keeps the active version's
        (so a caller that only changes sensors cannot drop them)."""
        current = self.load()
        latest = max([*self.versions(), current.version if current else 0])
        if spaces is None:
            spaces = dict(current.spaces) if current else {}
        calibration = Calibration(latest + 1, time.time(), dict(sensors), note, dict(spaces))
        self.history_dir.mkdir(parents=True, exist_ok=True)
        payload = calibration.to_json()
        _atomic_write(self.history_dir / f"v{calibration.version:06d}.json", payload)
        _atomic_write(self.path, payload)
        return calibration

    def rollback(self, version: int) -> Calibration:
        """Make an old version active again (saved as a new version)."""
        old = self.get(version)
        return self.save(old.sensors, note=f"rollback to v{version}", spaces=old.spaces)

    def import_json(self, data: Any, note: str = "imported") -> Calibration:
        """Validate an exported calibration and save it as a new active version."""
        parsed = Calibration.from_json(data, "imported calibration")
        return self.save(parsed.sensors, note=note, spaces=parsed.spaces)


def merge(
    base: Calibration | None, updates: dict[str, SensorCalibration]
) -> dict[str, SensorCalibration]:
    """Sensors of ``base`` with ``updates`` applied on top (sensors not updated are kept)."""
    merged = dict(base.sensors) if base else {}
    merged.update(updates)
    return merged


def _spaces_from_json(raw: Any, origin: str) -> dict[str, SpaceCalibration]:
    """A file's ``spaces`` object, validated; raises :class:`CalibrationFileError`."""
    if not isinstance(raw, dict):
        raise CalibrationFileError(f"{origin}: 'spaces' must be an object of tracking space ids")
    spaces: dict[str, SpaceCalibration] = {}
    for space_id, entry in raw.items():
        if not isinstance(entry, dict):
            raise CalibrationFileError(f"{origin}: space {space_id!r} must be an object")
        try:
            matrix = np.asarray(entry.get("T_world_from_space"), dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise CalibrationFileError(
                f"{origin}: space {space_id!r}: T_world_from_space is not a 4×4 matrix"
            ) from exc
        if not is_rigid(matrix, atol=1e-5):
            raise CalibrationFileError(
                f"{origin}: space {space_id!r}: T_world_from_space is not a rigid 4×4 transform "
                "(row-major, metres, last row 0 0 0 1)"
            )
        residual = entry.get("residual_mm")
        if residual is not None and not isinstance(residual, int | float):
            raise CalibrationFileError(f"{origin}: space {space_id!r}: bad residual_mm")
        details = entry.get("details", {})
        spaces[str(space_id)] = SpaceCalibration(
            matrix,
            str(entry.get("method", "unknown")),
            None if residual is None else float(residual),
            details if isinstance(details, dict) else {},
        )
    return spaces


def _atomic_write(path: Path, data: dict[str, Any]) -> None:
    payload = json.dumps(data, indent=2, allow_nan=False).encode("utf-8")
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as tmp:
            tmp.write(payload)
            tmp.flush()
            os.fsync(tmp.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
