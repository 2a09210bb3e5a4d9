"""C3D export for biomechanics tools (Visual3D, OpenSim, Mokka...): joints as markers, Z up, mm.

A small writer of our own (no dependency): one header block, a parameter section with the
``POINT`` and ``ANALOG`` groups, then float32 point data. Every person becomes 25 markers
labelled ``P<id>_<Joint>`` (e.g. ``P3_SpineBase``); a marker is invalid (residual −1) in frames
where that joint is unknown or the person absent. World (x, y, z) with +Y up becomes C3D
(x, −z, y) with +Z up, in millimetres; the frame rate is fixed (fused frames are resampled).

Layout (C3D.org "The C3D File Format User Guide"): 512-byte blocks, little-endian (processor
type 84, Intel); block 1 the header, blocks 2.. the parameters, then the data. A negative
``POINT:SCALE`` marks float data; each point is (x, y, z, residual) as float32.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from skelfuse.protocol.skeleton import JOINT_COUNT, JOINT_NAMES
from skelfuse.recording.take import Take, TakeError, frame_count, sample_at

F64 = npt.NDArray[np.float64]
BLOCK = 512
_INTEL = 84
_MAX_LABELS_PER_PARAMETER = 255


def z_up_mm(joints_m: F64) -> F64:
    """(..., 3) world points (+Y up, metres) → C3D (+Z up, millimetres): (x, −z, y)·1000."""
    out: F64 = np.stack([joints_m[..., 0], -joints_m[..., 2], joints_m[..., 1]], axis=-1)
    return out * 1000.0


@dataclass(frozen=True, slots=True)
class _Param:
    name: str
    kind: int  # -1 char, 1 byte, 2 int16, 4 float32
    dims: tuple[int, ...]
    data: bytes
    description: str = ""


def _char_param(name: str, values: list[str], description: str = "") -> _Param:
    width = max([len(v) for v in values] + [1])
    data = b"".join(v.encode("ascii", "replace").ljust(width) for v in values)
    return _Param(name, -1, (width, len(values)), data, description)


def _string_param(name: str, value: str, description: str = "") -> _Param:
    return _Param(name, -1, (len(value),), value.encode("ascii"), description)


def _int_param(name: str, value: int, description: str = "") -> _Param:
    return _Param(name, 2, (), struct.pack("<H" if value > 32767 else "<h", value), description)


def _float_param(name: str, value: float, description: str = "") -> _Param:
    return _Param(name, 4, (), struct.pack("<f", value), description)


def _group(group_id: int, name: str, description: str, params: list[_Param]) -> bytes:
    out = bytearray()
    name_b = name.encode("ascii")
    desc = description.encode("ascii")
    out += struct.pack("<bb", len(name_b), -group_id) + name_b
    out += struct.pack("<h", 2 + 1 + len(desc)) + struct.pack("<B", len(desc)) + desc
    for p in params:
        pname = p.name.encode("ascii")
        pdesc = p.description.encode("ascii")
        body = struct.pack("<bB", p.kind, len(p.dims)) + bytes(p.dims) + p.data
        body += struct.pack("<B", len(pdesc)) + pdesc
        out += struct.pack("<bb", len(pname), group_id) + pname
        out += struct.pack("<h", 2 + len(body)) + body
    return bytes(out)


def write_c3d(path: str | Path, points_mm: F64, labels: list[str], rate_hz: float) -> None:
    """Write markers to a C3D file.

    Args:
        path: output file.
        points_mm: (frames, markers, 3) float, millimetres, C3D frame (+Z up); NaN = invalid.
        labels: one per marker.
        rate_hz: frame rate.
    """
    frames, markers = points_mm.shape[:2]
    if len(labels) != markers:
        raise TakeError(f"{markers} markers but {len(labels)} labels")
    if frames == 0 or markers == 0:
        raise TakeError("nothing to write: no frames or no markers")
    if frames > 65535 or markers > 65535:
        raise TakeError(f"C3D holds at most 65535 frames and markers, got {frames}, {markers}")
    label_params = []
    for chunk in range(0, markers, _MAX_LABELS_PER_PARAMETER):
        suffix = "" if chunk == 0 else str(chunk // _MAX_LABELS_PER_PARAMETER + 1)
        part = labels[chunk : chunk + _MAX_LABELS_PER_PARAMETER]
        label_params.append(_char_param(f"LABELS{suffix}", part))
        label_params.append(_char_param(f"DESCRIPTIONS{suffix}", ["skelfuse joint"] * len(part)))

    def parameters(data_start: int) -> bytes:
        point = [
            _int_param("USED", markers, "markers"),
            _int_param("FRAMES", frames),
            _int_param("DATA_START", data_start),
            _float_param("SCALE", -1.0, "negative: float data"),
            _float_param("RATE", rate_hz),
            _string_param("UNITS", "mm"),
            *label_params,
        ]
        analog = [
            _int_param("USED", 0),
            _float_param("RATE", 0.0, "no analog channels"),
            _float_param("GEN_SCALE", 1.0),
        ]
        body = _group(1, "POINT", "3-D point parameters", point)
        body += _group(2, "ANALOG", "no analog data", analog)
        return body

    # The parameter section's size decides where the data starts; iterate once to settle it.
    blocks = 1
    while True:
        body = parameters(2 + blocks)
        needed = -(-(4 + len(body) + 2) // BLOCK)
        if needed <= blocks:
            break
        blocks = needed
    section = bytearray(struct.pack("<BBBB", 1, 0x50, blocks, _INTEL) + body)
    # Terminate the chain: the last record's "next" offset becomes 0.
    _zero_last_offset(section)
    section = section.ljust(blocks * BLOCK, b"\0")

    header = bytearray(BLOCK)
    struct.pack_into("<BB", header, 0, 2, 0x50)
    struct.pack_into("<hhhhh", header, 2, markers, 0, 1, frames if frames < 32768 else -1, 0)
    struct.pack_into("<f", header, 12, -1.0)
    struct.pack_into("<hh", header, 16, 2 + blocks, 0)
    struct.pack_into("<f", header, 20, rate_hz)
    if frames >= 32768:
        struct.pack_into("<H", header, 8, frames)

    data = np.zeros((frames, markers, 4), dtype="<f4")
    valid = np.asarray(np.isfinite(points_mm).all(axis=2), dtype=bool)
    data[..., :3] = np.where(valid[..., None], points_mm, 0.0)
    data[..., 3] = np.where(valid, 0.0, -1.0)
    payload = data.tobytes()
    payload += b"\0" * (-len(payload) % BLOCK)
    Path(path).write_bytes(bytes(header) + bytes(section) + payload)


def _zero_last_offset(section: bytearray) -> None:
    position = 4
    last_offset_at = None
    while position < len(section):
        name_len = abs(struct.unpack_from("<b", section, position)[0])
        if name_len == 0:
            break
        offset_at = position + 2 + name_len
        (offset,) = struct.unpack_from("<h", section, offset_at)
        last_offset_at = offset_at
        if offset == 0:
            break
        position = offset_at + offset
    if last_offset_at is not None:
        struct.pack_into("<h", section, last_offset_at, 0)


def export_c3d(take: Take, path: str | Path, fps: float = 30.0) -> int:
    """Every person's joints as markers on one regular clock; returns the frame count.

    The clock starts at the take's first fused instant; every person is sampled on that same
    clock (:func:`recording.take.sample_at`: linear within gaps up to 0.25 s), and a marker is
    invalid (residual −1) where its joint is unknown over a longer gap or the person absent.

    Raises:
        TakeError: nobody in the take, a frame rate that is not positive, or a take too long or
            with too many persons for C3D.
    """
    if not take.persons:
        raise TakeError("nobody was fused in this take: nothing to export")
    start = take.start_s
    offsets = np.arange(frame_count(start, take.end_s, fps)) / fps
    persons = list(take.persons.values())
    points = np.full((offsets.size, len(persons) * JOINT_COUNT, 3), np.nan)
    labels: list[str] = []
    for k, person in enumerate(persons):
        labels += [f"P{person.person_id}_{name}" for name in JOINT_NAMES]
        joints, _ = sample_at(person, start, offsets)
        points[:, k * JOINT_COUNT : (k + 1) * JOINT_COUNT] = z_up_mm(joints)
    write_c3d(path, points, labels, fps)
    return int(offsets.size)


@dataclass(frozen=True, slots=True)
class C3dData:
    rate_hz: float
    labels: list[str]
    points: F64
    """(frames, markers, 3) float64, NaN where the residual is negative."""


def read_c3d(path: str | Path) -> C3dData:
    """Read back what :func:`write_c3d` writes (float data, POINT labels); for tests and checks."""
    raw = Path(path).read_bytes()
    param_block = raw[0]
    markers, _, first, last = struct.unpack_from("<hhhh", raw, 2)
    (scale,) = struct.unpack_from("<f", raw, 12)
    (data_start,) = struct.unpack_from("<h", raw, 16)
    (rate,) = struct.unpack_from("<f", raw, 20)
    if scale >= 0:
        raise TakeError(f"{path}: integer C3D data is not supported by this reader")
    labels: list[str] = []
    frames = last - first + 1 if last > 0 else struct.unpack_from("<H", raw, 8)[0]
    position = (param_block - 1) * BLOCK + 4
    groups: dict[int, str] = {}
    while True:
        name_len, group_id = struct.unpack_from("<bb", raw, position)
        if name_len == 0:
            break
        name = raw[position + 2 : position + 2 + abs(name_len)].decode("ascii")
        offset_at = position + 2 + abs(name_len)
        (offset,) = struct.unpack_from("<h", raw, offset_at)
        if group_id < 0:
            groups[-group_id] = name
        elif groups.get(group_id) == "POINT" and name.startswith("LABELS"):
            _kind, ndims = struct.unpack_from("<bB", raw, offset_at + 2)
            dims = raw[offset_at + 4 : offset_at + 4 + ndims]
            width, count = dims[0], dims[1]
            start = offset_at + 4 + ndims
            labels += [
                raw[start + i * width : start + (i + 1) * width].decode("ascii").strip()
                for i in range(count)
            ]
        elif groups.get(group_id) == "POINT" and name == "FRAMES":
            (frames,) = struct.unpack_from("<H", raw, offset_at + 4)
        if offset == 0:
            break
        position = offset_at + offset
    start = (data_start - 1) * BLOCK
    data = np.frombuffer(raw, dtype="<f4", count=frames * markers * 4, offset=start)
    data = data.reshape(frames, markers, 4).astype(np.float64)
    points = data[..., :3].copy()
    points[data[..., 3] < 0] = np.nan
    return C3dData(float(rate), labels, points)
