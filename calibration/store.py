"""Persisted calibration: each sensor's ``T_world_from_sensor``, versioned, crash-safe.

The active calibration lives in ``<data_dir>/calibration.json``. Every save writes a new
version: the file is written to a temporary name, fsync'ed, renamed over the old one and the
folder fsync'ed, so a crash leaves either the old or the new version, never half of one. The
previous versions are kept in ``<data_dir>/calibration-history/``.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from protocol.transform import Matrix4, is_rigid

FILE_NAME = "calibration.json"
FORMAT_VERSION = 1


class CalibrationError(Exception):
    """Base class of calibration errors."""


class CalibrationFileError(CalibrationError):
    """The stored calibration cannot be read; the message says which file and why."""


@dataclass(frozen=True, slots=True)
class SensorCalibration:
    """One sensor's pose in the world (4×4 float64, metres) and how it was obtained."""

    T_world_from_sensor: Matrix4
    method: str
    residual_mm: float | None = None


@dataclass(frozen=True, slots=True)
class Calibration:
    version: int
    created_unix_s: float
    sensors: dict[str, SensorCalibration]

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT_VERSION,
            "version": self.version,
            "created_unix_s": self.created_unix_s,
            "sensors": {
                sensor_id: {
                    "T_world_from_sensor": s.T_world_from_sensor.tolist(),
                    "method": s.method,
                    "residual_mm": s.residual_mm,
                }
                for sensor_id, s in sorted(self.sensors.items())
            },
        }

    @staticmethod
    def from_json(data: Any, origin: str) -> Calibration:
        if not isinstance(data, dict) or data.get("format") != FORMAT_VERSION:
            raise CalibrationFileError(
                f"{origin}: not a calibration file of format {FORMAT_VERSION}"
            )
        sensors: dict[str, SensorCalibration] = {}
        for sensor_id, entry in dict(data.get("sensors", {})).items():
            matrix = np.asarray(entry.get("T_world_from_sensor"), dtype=np.float64)
            if not is_rigid(matrix, atol=1e-5):
                raise CalibrationFileError(
                    f"{origin}: sensor {sensor_id!r}: T_world_from_sensor is not a rigid 4×4"
                )
            residual = entry.get("residual_mm")
            sensors[str(sensor_id)] = SensorCalibration(
                matrix,
                str(entry.get("method", "unknown")),
                None if residual is None else float(residual),
            )
        return Calibration(
            int(data.get("version", 0)), float(data.get("created_unix_s", 0)), sensors
        )


class CalibrationStore:
    """Reads and writes the calibration in one data folder."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)

    @property
    def path(self) -> Path:
        return self.data_dir / FILE_NAME

    def load(self) -> Calibration | None:
        """The active calibration, or None if none was ever saved."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CalibrationFileError(f"{self.path}: not valid JSON ({exc})") from exc
        return Calibration.from_json(data, str(self.path))

    def save(self, sensors: dict[str, SensorCalibration]) -> Calibration:
        """Write a new version atomically and return it."""
        current = self.load()
        calibration = Calibration(
            version=(current.version + 1) if current else 1,
            created_unix_s=time.time(),
            sensors=dict(sensors),
        )
        self.data_dir.mkdir(parents=True, exist_ok=True)
        if current is not None:
            history = self.data_dir / "calibration-history"
            history.mkdir(exist_ok=True)
            _atomic_write(history / f"v{current.version:06d}.json", current.to_json())
        _atomic_write(self.path, calibration.to_json())
        return calibration


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
