"""A pose file: a recorded or simulated trajectory of the body a depth camera is fixed to.

Two formats (docs/sensors.md, "Pose files"), told apart by the file's extension:

- CSV (any extension but the two below): a header naming the columns, then one sample a row.
  Time column ``t_ns`` (ns since the Unix epoch on the agent's wall clock) **or** ``t_s``
  (seconds from the start of the agent's pose source); pose columns ``px,py,pz`` (metres) and
  ``qx,qy,qz,qw`` (unit quaternion, body axes into space axes), in any order. Blank lines and
  lines starting with ``#`` are skipped.
- JSON lines (``.jsonl``, ``.ndjson``): one object a line, ``{"t_s": 0.0, "pose": [px, py, pz,
  qx, qy, qz, qw]}`` (or ``"t_ns"``), the same 7 numbers as a frame's wire ``pose``.

Times strictly increase; quaternions are unit within 1e-3 (the protocol's tolerance) and are
normalised. Every error names the file and the line. :func:`write_pose_file` writes the CSV form
(a simulator's trajectory, a tracker's recording).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from skelfuse.agent.sources.base import SensorError
from skelfuse.protocol.messages import SensorPose
from skelfuse.protocol.sensor_pose import PoseTrack

POSE_COLUMNS: Final = ("px", "py", "pz", "qx", "qy", "qz", "qw")
JSON_SUFFIXES: Final = (".jsonl", ".ndjson")


@dataclass(frozen=True, slots=True)
class PoseFile:
    """A parsed pose file.

    ``times_s``: sample instants in seconds after ``t0_ns`` (absolute files: ``t0_ns`` is the
    first sample's ``t_ns``; relative files: 0 and the times are the file's ``t_s``);
    ``absolute``: True for ``t_ns`` files; ``poses``: the samples (unit quaternions).
    """

    times_s: tuple[float, ...]
    poses: tuple[SensorPose, ...]
    absolute: bool
    t0_ns: int


def read_pose_file(path: Path) -> PoseFile:
    """Parse ``path`` (CSV, or JSON lines for ``.jsonl`` / ``.ndjson``).

    Raises:
        SensorError: unreadable file, no samples, or a bad line (``PATH:LINE: what is wrong``):
            unknown/missing/duplicate header columns, a wrong count of values, a value that is
            not a finite number (``t_ns`` must be an integer), a quaternion whose norm is not
            within 1e-3 of 1, a time not after the previous one, mixed time keys.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SensorError(f"pose file {path}: {exc}") from exc
    rows = _json_rows(path, text) if path.suffix.lower() in JSON_SUFFIXES else _csv_rows(path, text)
    times: list[float] = []
    poses: list[SensorPose] = []
    absolute: bool | None = None
    t0_ns = 0
    previous: int | float | None = None
    for line, key, t, values in rows:
        if absolute is None:
            absolute = key == "t_ns"
            t0_ns = int(t) if absolute else 0
        elif absolute != (key == "t_ns"):
            raise SensorError(f"{path}:{line}: {key} in a file whose times are not {key}")
        if previous is not None and t <= previous:
            raise SensorError(f"{path}:{line}: time {t} is not after the previous one {previous}")
        previous = t
        times.append((int(t) - t0_ns) / 1e9 if absolute else float(t))
        poses.append(_pose(path, line, values))
    if absolute is None:
        raise SensorError(f"pose file {path}: no samples")
    return PoseFile(tuple(times), tuple(poses), absolute, t0_ns)


def write_pose_file(
    path: Path,
    times: Sequence[float] | Sequence[int],
    poses: Sequence[SensorPose],
    *,
    absolute: bool,
) -> None:
    """Write a CSV pose file :func:`read_pose_file` reads back: a simulated or recorded
    trajectory (``times``: ``t_ns`` ints when ``absolute``, else ``t_s`` seconds).

    Floats are written with ``repr`` (round-trip exact).

    Raises:
        ValueError: lengths differ; OSError: the file cannot be written.
    """
    if len(times) != len(poses):
        raise ValueError(f"{len(times)} times for {len(poses)} poses")
    header = ("t_ns" if absolute else "t_s", *POSE_COLUMNS)
    lines = [",".join(header)]
    for t, pose in zip(times, poses, strict=True):
        stamp = str(int(t)) if absolute else repr(float(t))
        values = (*pose.position_m, *pose.rotation_xyzw)
        lines.append(",".join([stamp, *(repr(float(v)) for v in values)]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


Row = tuple[int, str, int | float, list[float]]


def _csv_rows(path: Path, text: str) -> Iterator[Row]:
    header: list[str] | None = None
    for line, raw in enumerate(text.splitlines(), start=1):
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        cells = [c.strip() for c in stripped.split(",")]
        if header is None:
            header = cells
            _check_header(path, line, header)
            continue
        if len(cells) != len(header):
            raise SensorError(f"{path}:{line}: {len(cells)} values for {len(header)} columns")
        named = dict(zip(header, cells, strict=True))
        key = "t_ns" if "t_ns" in named else "t_s"
        t = _time(path, line, key, named[key])
        yield line, key, t, [_number(path, line, c, named[c]) for c in POSE_COLUMNS]


def _check_header(path: Path, line: int, header: list[str]) -> None:
    expected = f"t_ns or t_s, then {','.join(POSE_COLUMNS)} in any order"
    times = [c for c in header if c in ("t_ns", "t_s")]
    unknown = [c for c in header if c not in (*POSE_COLUMNS, "t_ns", "t_s")]
    missing = [c for c in POSE_COLUMNS if c not in header]
    if unknown or missing or len(times) != 1 or len(set(header)) != len(header):
        raise SensorError(
            f"{path}:{line}: header {','.join(header)!r} (unknown {unknown}, missing {missing}): "
            f"expected the columns {expected}"
        )


def _json_rows(path: Path, text: str) -> Iterator[Row]:
    for line, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        try:
            item = json.loads(raw)
        except json.JSONDecodeError as exc:
            raise SensorError(f"{path}:{line}: not JSON ({exc.msg})") from exc
        if not isinstance(item, dict):
            raise SensorError(f"{path}:{line}: expected an object with t_s or t_ns and pose")
        keys = [k for k in ("t_ns", "t_s") if k in item]
        pose = item.get("pose")
        if len(keys) != 1 or not isinstance(pose, list) or len(pose) != 7:
            raise SensorError(
                f'{path}:{line}: expected {{"t_s" or "t_ns": time, "pose": '
                "[px, py, pz, qx, qy, qz, qw]}"
            )
        t = _time(path, line, keys[0], item[keys[0]])
        values = [_number(path, line, name, v) for name, v in zip(POSE_COLUMNS, pose, strict=True)]
        yield line, keys[0], t, values


def _time(path: Path, line: int, key: str, value: object) -> int | float:
    if key == "t_ns":
        try:
            if isinstance(value, (bool, float)):
                raise ValueError
            return int(value) if isinstance(value, int) else int(str(value), 10)
        except ValueError:
            raise SensorError(f"{path}:{line}: t_ns {value!r} is not an integer") from None
    return _number(path, line, key, value)


def _number(path: Path, line: int, name: str, value: object) -> float:
    try:
        if isinstance(value, bool):
            raise ValueError
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise SensorError(f"{path}:{line}: {name} {value!r} is not a number") from None
    if not math.isfinite(number):
        raise SensorError(f"{path}:{line}: {name} is {number}, not finite")
    return number


def _pose(path: Path, line: int, values: list[float]) -> SensorPose:
    q = values[3:]
    norm = math.sqrt(sum(v * v for v in q))
    if abs(norm - 1.0) > 1e-3:
        raise SensorError(f"{path}:{line}: quaternion norm {norm:.6f} is not 1 (within 1e-3)")
    x, y, z, w = (v / norm for v in q)
    return SensorPose((values[0], values[1], values[2]), (x, y, z, w))


class FilePoseSource:
    """A pose file read at the agent's instants.

    Args:
        track: the parsed file (:func:`read_pose_file`).
        clock_ns: the agent's wall clock (the capture stamps' clock), read once at construction
            to anchor a relative (``t_s``) file: its 0 is then.
        start_ns: anchor a relative file here instead (ignored for ``t_ns`` files).
        offset_ns: move the whole track later on the agent's clock by this much (a sample of
            file time f applies at agent time f + offset): a tracker clock that differs.
        loop: repeat the track every (last − first) seconds: make the last sample the first
            pose again for a seamless loop.
        max_gap_s, max_extrapolation_s: as :class:`~skelfuse.protocol.sensor_pose.PoseTrack`.

    Raises:
        SensorError: ``loop`` with fewer than two samples.
    """

    def __init__(
        self,
        track: PoseFile,
        *,
        clock_ns: Callable[[], int] = time.time_ns,
        start_ns: int | None = None,
        offset_ns: int = 0,
        loop: bool = False,
        max_gap_s: float = 0.25,
        max_extrapolation_s: float = 0.05,
    ) -> None:
        if loop and len(track.times_s) < 2:
            raise SensorError("a looped pose file needs at least two samples")
        self._track = PoseTrack(
            track.times_s,
            track.poses,
            max_gap_s=max_gap_s,
            max_extrapolation_s=max_extrapolation_s,
        )
        anchor = track.t0_ns if track.absolute else (clock_ns() if start_ns is None else start_ns)
        self._zero_ns = anchor + offset_ns
        self._first_s = track.times_s[0]
        self._period_s = track.times_s[-1] - track.times_s[0] if loop else None
        self.last_miss = ""

    def pose_at(self, t_ns: int) -> SensorPose | None:
        """The file's pose at agent time ``t_ns``; None outside the track or in a gap."""
        t_s = (t_ns - self._zero_ns) / 1e9
        if self._period_s is not None:
            t_s = self._first_s + (t_s - self._first_s) % self._period_s
        pose = self._track.at(t_s)
        if pose is None:
            times = self._track.times_s
            self.last_miss = (
                "before the pose file's first sample"
                if t_s < times[0]
                else "after the pose file's last sample"
                if t_s > times[-1]
                else "in a gap of the pose file"
            )
        return pose

    def close(self) -> None:
        """Nothing to release (the file was read whole)."""
