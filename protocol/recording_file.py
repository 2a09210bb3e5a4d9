"""The skelfuse recording file, version 1 (specified in ``docs/recording.md``).

Layout: a plain concatenation of msgpack objects, nothing else (no index, no footer to seek):

1. a **header** map: ``format`` = ``"skelfuse-recording"``, ``version`` = 1, ``created_unix_s``,
   ``server_version``, ``name``, ``calibration`` {sensor_id: {``T_world_from_sensor``: 16
   floats row-major, ``method``, ``state``, and ``lag_s`` only when the sensor has a clock
   lag}} and ``sensors`` {sensor_id: {``type``,
   ``pose_state``}} as the server knew them when recording started;
2. **records**, each an array ``[t_server_ns, sensor_id, kind, payload]``: the server's wall
   clock (int ns) when the message arrived, the sender's id, ``"hello"`` or ``"frame"``, and the
   message's wire bytes exactly as received (``docs/protocol.md``);
3. on a clean stop, one **end** record ``[t_server_ns, "", "end", b""]``.

A recording cut short (crash, power loss) is readable up to its last complete record: the
reader stops there and says how much it could read. Anything else that does not parse is an
error naming the byte offset and the number of records read before it.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Final

import msgpack
import numpy as np

from skelfuse.protocol.transform import Matrix4, is_rigid

logger = logging.getLogger(__name__)

FORMAT_NAME: Final = "skelfuse-recording"
FORMAT_VERSION: Final = 1
FILE_SUFFIX: Final = ".sfrec"
KINDS: Final = frozenset({"hello", "frame", "end"})
_MAX_PAYLOAD_BYTES: Final = 1 << 20
SPACE_KEY_PREFIX: Final = "space:"
"""The header's ``calibration`` holds a tracking space's ``T_world_from_space`` (moving sensors)
under this prefix and the space id, e.g. ``space:room``; no sensor id contains ``:``."""


class RecordingError(Exception):
    """A recording that cannot be read; the message says which file, where and why."""


class RecordingTruncated(RecordingError):
    """The file ends inside a record (raised only when reading with ``strict=True``)."""


@dataclass(frozen=True, slots=True)
class Record:
    """One recorded message: arrival time on the server (ns), sender, kind, wire bytes."""

    t_server_ns: int
    sensor_id: str
    kind: str
    payload: bytes


@dataclass(frozen=True, slots=True)
class SensorPose:
    """A sensor's ``T_world_from_sensor`` (4×4 float64, metres), where it came from, and its
    calibrated clock lag (seconds its stamps show events late; None: none stored)."""

    T_world_from_sensor: Matrix4
    method: str
    state: str
    lag_s: float | None = None


@dataclass(frozen=True, slots=True)
class Header:
    created_unix_s: float
    server_version: str
    name: str = ""
    calibration: dict[str, SensorPose] = field(default_factory=dict)
    sensors: dict[str, dict[str, Any]] = field(default_factory=dict)
    version: int = FORMAT_VERSION

    def to_msgpack(self) -> bytes:
        body = {
            "format": FORMAT_NAME,
            "version": self.version,
            "created_unix_s": float(self.created_unix_s),
            "server_version": self.server_version,
            "name": self.name,
            "calibration": {
                sensor_id: _pose_entry(pose) for sensor_id, pose in sorted(self.calibration.items())
            },
            "sensors": {k: dict(v) for k, v in sorted(self.sensors.items())},
        }
        packed: bytes = msgpack.packb(body, use_bin_type=True)
        return packed

    @staticmethod
    def from_object(raw: Any, origin: str) -> Header:
        if not isinstance(raw, dict) or raw.get("format") != FORMAT_NAME:
            raise RecordingError(f"{origin}: not a skelfuse recording (no {FORMAT_NAME} header)")
        version = raw.get("version")
        if version != FORMAT_VERSION:
            raise RecordingError(
                f"{origin}: recording format version {version!r}; this build reads version "
                f"{FORMAT_VERSION} (upgrade skelfuse)"
            )
        calibration: dict[str, SensorPose] = {}
        for sensor_id, entry in dict(raw.get("calibration") or {}).items():
            try:
                matrix = np.asarray(entry["T_world_from_sensor"], dtype=np.float64).reshape(4, 4)
            except (KeyError, TypeError, ValueError) as exc:
                raise RecordingError(f"{origin}: bad calibration for {sensor_id!r}") from exc
            if not is_rigid(matrix, atol=1e-5):
                raise RecordingError(f"{origin}: calibration of {sensor_id!r} is not rigid")
            lag = entry.get("lag_s")
            if lag is not None and (not isinstance(lag, int | float) or not np.isfinite(lag)):
                raise RecordingError(f"{origin}: bad lag_s for {sensor_id!r}")
            calibration[str(sensor_id)] = SensorPose(
                matrix,
                str(entry.get("method", "unknown")),
                str(entry.get("state", "stored")),
                None if lag is None else float(lag),
            )
        sensors = {str(k): dict(v) for k, v in dict(raw.get("sensors") or {}).items()}
        return Header(
            created_unix_s=float(raw.get("created_unix_s", 0.0)),
            server_version=str(raw.get("server_version", "")),
            name=str(raw.get("name", "")),
            calibration=calibration,
            sensors=sensors,
            version=FORMAT_VERSION,
        )


def _pose_entry(pose: SensorPose) -> dict[str, Any]:
    """A header's calibration entry; ``lag_s`` only when set, so files without lags keep their
    bytes."""
    entry: dict[str, Any] = {
        "T_world_from_sensor": [float(x) for x in pose.T_world_from_sensor.reshape(16)],
        "method": pose.method,
        "state": pose.state,
    }
    if pose.lag_s is not None:
        entry["lag_s"] = float(pose.lag_s)
    return entry


def pack_record(t_server_ns: int, sensor_id: str, kind: str, payload: bytes) -> bytes:
    """The bytes of one record (deterministic)."""
    packed: bytes = msgpack.packb(
        [int(t_server_ns), sensor_id, kind, bytes(payload)], use_bin_type=True
    )
    return packed


@dataclass(slots=True)
class ReadStatus:
    """What a read found: records read, bytes consumed, whether the file ended cleanly."""

    records: int = 0
    bytes_read: int = 0
    file_bytes: int = 0
    complete: bool = False
    truncated: bool = False

    def describe(self) -> str:
        if self.complete:
            return f"{self.records} records, complete"
        state = "truncated" if self.truncated else "not closed (no end record)"
        return (
            f"{self.records} records readable ({self.bytes_read} of {self.file_bytes} bytes), "
            f"{state}"
        )


class RecordingReader:
    """Reads a recording: ``header`` at once, then :meth:`records` in file order.

    Args:
        path: the ``.sfrec`` file.
        strict: raise :class:`RecordingTruncated` when the file ends inside a record; by
            default a truncated tail is logged and reading stops at the last complete record.
    """

    def __init__(self, path: str | Path, *, strict: bool = False) -> None:
        self.path = Path(path)
        self.strict = strict
        self.status = ReadStatus()
        try:
            self._file: BinaryIO = self.path.open("rb")
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot open ({exc.strerror})") from exc
        self.status.file_bytes = self.path.stat().st_size
        self._unpacker = msgpack.Unpacker(
            self._file, raw=False, strict_map_key=False, max_buffer_size=16 * _MAX_PAYLOAD_BYTES
        )
        try:
            raw = self._unpacker.unpack()
        except msgpack.OutOfData as exc:
            self.close()
            raise RecordingError(f"{self.path}: empty or truncated header") from exc
        except (ValueError, msgpack.UnpackException) as exc:
            self.close()
            raise RecordingError(f"{self.path}: not a skelfuse recording ({exc})") from exc
        try:
            self.header = Header.from_object(raw, str(self.path))
        except RecordingError:
            self.close()
            raise
        self.status.bytes_read = self._unpacker.tell()

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._file.close()

    def records(self) -> Iterator[Record]:
        """Every record in file order (the ``end`` record is consumed, not yielded)."""
        status = self.status
        while True:
            try:
                raw = self._unpacker.unpack()
            except msgpack.OutOfData:
                break
            except (ValueError, msgpack.UnpackException) as exc:
                raise RecordingError(
                    f"{self.path}: corrupt data at byte {status.bytes_read} after "
                    f"{status.records} readable records ({exc})"
                ) from exc
            record = _to_record(raw)
            if record is None:
                raise RecordingError(
                    f"{self.path}: malformed record at byte {status.bytes_read} after "
                    f"{status.records} readable records"
                )
            status.bytes_read = self._unpacker.tell()
            if record.kind == "end":
                status.complete = True
                return
            status.records += 1
            yield record
        if status.bytes_read < status.file_bytes:
            status.truncated = True
            message = (
                f"{self.path}: truncated: the last {status.file_bytes - status.bytes_read} "
                f"bytes are an incomplete record; {status.records} records "
                f"({status.bytes_read} of {status.file_bytes} bytes) were readable"
            )
            if self.strict:
                raise RecordingTruncated(message)
            logger.warning("%s", message)
        elif not status.complete:
            logger.warning(
                "%s: no end record (the recorder did not stop cleanly); %d records read",
                self.path,
                status.records,
            )


def _to_record(raw: Any) -> Record | None:
    if not isinstance(raw, list) or len(raw) != 4:
        return None
    t_ns, sensor_id, kind, payload = raw
    if (
        type(t_ns) is not int
        or not isinstance(sensor_id, str)
        or kind not in KINDS
        or not isinstance(payload, bytes)
    ):
        return None
    return Record(t_ns, sensor_id, kind, payload)


def read_recording(path: str | Path, *, strict: bool = False) -> tuple[Header, list[Record]]:
    """The header and every record of a recording (see :class:`RecordingReader`)."""
    with RecordingReader(path, strict=strict) as reader:
        return reader.header, list(reader.records())


def write_recording(
    out: str | Path | BinaryIO, header: Header, records: list[Record], *, end: bool = True
) -> None:
    """Write a whole recording at once (tests, benchmarks, converters)."""
    chunks = [header.to_msgpack()]
    chunks += [pack_record(r.t_server_ns, r.sensor_id, r.kind, r.payload) for r in records]
    if end:
        t_end = records[-1].t_server_ns if records else 0
        chunks.append(pack_record(t_end, "", "end", b""))
    data = b"".join(chunks)
    if isinstance(out, str | Path):
        Path(out).write_bytes(data)
    else:
        out.write(data)


@dataclass(frozen=True, slots=True)
class Summary:
    """What the REST list shows about a recording file."""

    records: int
    frames: int
    duration_s: float
    sensors: tuple[str, ...]
    complete: bool
    truncated: bool


def summarize(path: str | Path) -> Summary:
    """Scan a recording (reads it all once) for its duration, sensors and state."""
    frames = 0
    sensors: set[str] = set()
    first: int | None = None
    last = 0
    with RecordingReader(path) as reader:
        for record in reader.records():
            first = record.t_server_ns if first is None else first
            last = record.t_server_ns
            sensors.add(record.sensor_id)
            frames += record.kind == "frame"
        status = reader.status
    duration = 0.0 if first is None else (last - first) / 1e9
    return Summary(
        status.records, frames, duration, tuple(sorted(sensors)), status.complete, status.truncated
    )


__all__ = [
    "FILE_SUFFIX",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "Header",
    "ReadStatus",
    "Record",
    "RecordingError",
    "RecordingReader",
    "RecordingTruncated",
    "SensorPose",
    "Summary",
    "pack_record",
    "read_recording",
    "summarize",
    "write_recording",
]
